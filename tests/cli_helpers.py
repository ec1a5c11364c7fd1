"""The command line run in-process, for the command tests (tests/ is on sys.path)."""

from __future__ import annotations

import json

from cli.main import main


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """``zcut ARGV`` in this process: (exit status, stdout, stderr)."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:  # a usage error: argparse exits with the user-error status
        rc = e.code
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def accuracy_report(capsys, *argv) -> dict:
    """``zcut accuracy ARGV --json``'s report (exit 0 asserted), its frames without the bin check (only a
    log's frames carry it), so that a log's and its results files' reports compare equal."""
    rc, out, err = run_cli(capsys, "accuracy", *argv, "--json")
    assert rc == 0, err
    rep = json.loads(out)
    for f in rep["frames"]:
        f.pop("bin_check"), f.pop("bin_flagged")
    return rep


def synth_log(path, *, parts: str, frames: int, seed: int, size: str):
    """``zcut synth`` a log of ``frames`` frames of ``parts`` to ``path`` (``size`` as ``--size`` takes it)."""
    assert main(["synth", "-o", str(path), "--parts", parts, "--frames", str(frames), "--seed", str(seed),
                 "--size", size]) == 0
    return path


def synth_logs(d, specs, *, size: str):
    """:func:`synth_log` ``d / NAME.mcap`` for each (NAME, parts, frames, seed) of ``specs``: returns ``d``."""
    for name, parts, frames, seed in specs:
        synth_log(d / f"{name}.mcap", parts=parts, frames=frames, seed=seed, size=size)
    return d


def synth_with_bin_model(d, *, parts: str, seed: int, size: str, empty_seed: int = 3,
                         names: tuple[str, str] = ("log.mcap", "empty.mcap")):
    """In folder ``d``: a log of two frames of ``parts`` (``zcut synth``, ``size`` as ``--size`` takes it), a
    log of two frames of the empty bin (``empty_seed``) and its bin model ``bin.ply`` (``zcut bin-model``):
    the (log, empty, model) paths."""
    log, empty, model = d / names[0], d / names[1], d / "bin.ply"
    synth_log(log, parts=parts, frames=2, seed=seed, size=size)
    assert main(["synth", "-o", str(empty), "--empty", "--frames", "2", "--seed", str(empty_seed), "--size", size]) == 0
    assert main(["bin-model", str(empty), "-o", str(model)]) == 0
    return log, empty, model
