"""The fuzz suite's fast subset: a fixed-seed sample of every generator of ``fuzzgen`` (about 230
hostile inputs and command lines), each case run as the real ``zcut`` command under a time and a
memory cap, and every one must be clean (exit 0, 3, or 1 with one ``error: `` line; no traceback,
hang, crash, memory blow-up, silent loss, modified input or leftover temporary file).

The long run is ``bench/fuzz_cli.py --cases 10000``. A non-clean case prints its reproducer: the
case's folder is kept (``cd DIR && zcut ARGS``, see the assertion message).
"""

from __future__ import annotations

import os
from pathlib import Path

import fuzzgen
import fuzzlib
import pytest

SEED = 20250611
COUNTS = {"mcap_bytes": 30, "mcap_struct": 30, "cloud": 30, "image": 20, "pcd": 20, "ply": 20, "cli": 25, "paths": 20,
          "config": 15, "labels": 12}
#: the compression bombs that must be refused (or read) at once, each by two commands
BOMB_KINDS = ("topics-check", "replay-json")
#: a case's time cap here (honest cases take well under 2 s of CPU; the long run allows 30 s)
TIMEOUT_S = 20.0
#: Findings that need a change outside the log readers (the pipeline, the command line): case id ->
#: the finding. They are reported (xfail) instead of failing the suite; one that becomes clean
#: fails ``test_pending_findings_are_still_open``: remove it from here.
PENDING: dict[str, str] = {}

pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def corpus(work, warmup_run):
    """The corpus, its process not running the kernels' warm-up again: the session's run of it
    (tests/conftest.py, ``warmup_run``: the one tests/cli/test_cli_warmup.py checks) compiled every kernel into
    numba's cache, so that no case compiles one under its time cap."""
    assert warmup_run.returncode == 0, warmup_run.stderr[-3000:]
    return fuzzgen.ensure_corpus(work / "corpus", warmed_up=True)


@pytest.fixture(scope="module")
def server():
    """One warm fork server (two jobs) for every fork run of the module: the corpus's cases, the caps' and the
    real command's runs (each started its own, ~2.6 CPU s of imports; a server is left as it was by the
    children it forks)."""
    s = fuzzlib.ForkServer(jobs=2)
    yield s
    s.close()


@pytest.fixture(scope="module")
def outcomes(work, corpus, server) -> dict[str, fuzzlib.Outcome]:
    keep = Path(os.environ.get("ZCUT_FUZZ_KEEP", work / "findings"))
    cases = [*fuzzgen.make_cases(corpus, COUNTS, SEED),
             *(fuzzgen.bomb_case(corpus, i, kind, f"mcap_bomb-fast-{i:02d}{kind[0]}", timeout_s=None)
               for i in fuzzgen.CHEAP_BOMBS for kind in BOMB_KINDS)]
    return {o.case.id: o for o in fuzzlib.run_cases(cases, work / "cases", jobs=2, keep=keep, timeout_s=TIMEOUT_S,
                                                    runner=server)}


def _report(o: fuzzlib.Outcome, keep: Path) -> str:
    text = (f"{o.klass}: {o.case.id} ({o.case.what[:120]})\n    cd {keep / o.case.id} && {o.case.command_line()[:300]}"
            f"\n    -> {o.detail[:300]}")
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def test_every_case_was_run(outcomes):
    assert len(outcomes) == sum(COUNTS.values()) + len(fuzzgen.CHEAP_BOMBS) * len(BOMB_KINDS)
    assert {o.case.generator for o in outcomes.values()} == set(fuzzgen.GENERATORS)


@pytest.mark.parametrize("generator", sorted(fuzzgen.GENERATORS))
def test_every_case_is_clean(outcomes, work, generator):
    keep = Path(os.environ.get("ZCUT_FUZZ_KEEP", work / "findings"))
    bad = [o for o in outcomes.values()
           if o.case.generator == generator and o.klass != "clean" and o.case.id not in PENDING]
    assert not bad, f"{len(bad)} non-clean case(s):\n" + "\n".join(_report(o, keep) for o in bad)


def test_pending_findings_are_still_open(outcomes, work):
    keep = Path(os.environ.get("ZCUT_FUZZ_KEEP", work / "findings"))
    fixed = [k for k in PENDING if outcomes[k].klass == "clean"]
    assert not fixed, f"now clean, remove from PENDING: {', '.join(fixed)}"
    if PENDING:
        pytest.xfail(f"{len(PENDING)} pending finding(s) outside replay/logs:\n"
                     + "\n".join(f"{PENDING[k]}\n  {_report(outcomes[k], keep)}" for k in PENDING))


# ---------------------------------------------------------------------------------------------- the runner itself
def test_cases_are_reproducible(corpus):
    a = fuzzgen.make_case(corpus, "cloud", 3, 17)
    b = fuzzgen.make_case(corpus, "cloud", 3, 17)
    assert (a.argv, a.files, a.what) == (b.argv, b.files, b.what)
    assert fuzzgen.make_case(corpus, "cloud", 4, 17).files != a.files


@pytest.mark.parametrize("rc,stderr,stdout,expect", [
    (0, "", "", "clean"),
    (3, "warning: data loss: frame 2 lost\n", "", "clean"),
    (1, "usage: zcut ...\nerror: bad thing\n", "", "clean"),
    (1, "error: one\nerror: two\n", "", "bad-exit"),
    (1, "", "", "bad-exit"),
    (2, "error: x\n", "", "bad-exit"),
    (1, "Traceback (most recent call last):\n  File \"x.py\", line 1, in f\nValueError: boom\n", "", "traceback"),
    (0, "Exception in thread T:\nTraceback (most recent call last):\nKeyError: 1\n", "", "traceback"),
    (1, "error: not enough memory\n", "", "memory"),
    (1, "MemoryError: std::bad_alloc\n", "", "memory"),
    (0, "", "check: 2 frames decoded (2 with colour)\n", "loss-exit0"),
    (0, "", "check: 3 frames decoded (3 with colour)\n", "clean"),
    (0, "", '{"frames": [{}, {}]}', "loss-exit0"),
])
def test_classify(rc, stderr, stdout, expect):
    case = fuzzlib.Case("x", "g", "w", ["topics", "--check", "l.mcap"], expect_frames=3,
                        count="json" if stdout.startswith("{") else "check")
    assert fuzzlib.classify(case, rc=rc, sig=None, timed_out=False, stdout=stdout, stderr=stderr, modified=[],
                            left=[])[0] == expect


def test_classify_signals_and_files():
    case = fuzzlib.Case("x", "g", "w", ["topics", "l.mcap"])
    kw = dict(stdout="", stderr="", modified=[], left=[])
    assert fuzzlib.classify(case, rc=None, sig=11, timed_out=False, **kw)[0] == "crash"
    assert fuzzlib.classify(case, rc=None, sig=9, timed_out=True, **kw)[0] == "hang"
    assert fuzzlib.classify(case, rc=0, sig=None, timed_out=False, stdout="", stderr="", modified=["l.mcap changed"],
                            left=[])[0] == "input-modified"
    assert fuzzlib.classify(case, rc=0, sig=None, timed_out=False, stdout="", stderr="", modified=[],
                            left=[".out.x.partial.mcap"])[0] == "leftover"


def test_snapshot_sees_changes_links_and_special_files(tmp_path):
    case = fuzzlib.Case("x", "g", "w", [], files={"a.mcap": b"one", "d/b.txt": b"two"},
                        special=[("fifo", "p", ""), ("symlink", "s", "a.mcap"), ("hardlink", "h", "a.mcap"),
                                 ("dir", "e", "")])
    case.materialize(tmp_path)
    before = fuzzlib.snapshot(tmp_path)
    (tmp_path / "a.mcap").write_bytes(b"ONE")  # through the hard link too
    os.unlink(tmp_path / "s")
    os.symlink("d/b.txt", tmp_path / "s")
    (tmp_path / "new.partial").write_bytes(b"")
    after = fuzzlib.snapshot(tmp_path)
    assert sorted(fuzzlib.modified_inputs(before, after, set())) == ["a.mcap changed", "h changed", "s changed"]
    assert fuzzlib.modified_inputs(before, after, {"a.mcap", "h", "s"}) == []
    assert fuzzlib.leftovers(before, after) == ["new.partial"]


def test_runner_caps_memory_and_time(tmp_path, server):
    """The caps are real: a legitimately huge synthesis is killed above 1 GiB resident (memory), the
    address-space backstop turns an allocation into a MemoryError (memory), a long run is killed at a
    1 s cap (hang, with its process group)."""
    big = ["synth", "-o", "o.mcap", "--size", "4000x4000"]  # under the readers' caps, which synth refuses up front
    cases = [
        fuzzlib.Case("rss", "meta", "huge synth", big, timeout_s=120),
        fuzzlib.Case("time", "meta", "long synth", ["synth", "-o", "o.mcap", "--size", "2048x2048", "--frames", "50"],
                     timeout_s=1.0),
    ]
    got = {o.case.id: o for o in fuzzlib.run_cases(cases, tmp_path / "w", jobs=2, mem_bytes=1 << 30,
                                                     keep=tmp_path / "keep", runner=server)}
    assert got["rss"].klass == "memory" and "resident" in got["rss"].detail, got["rss"].detail
    assert got["time"].klass == "hang" and ".py:" in got["time"].detail  # where it was (a faulthandler dump)
    assert (tmp_path / "keep" / "rss.cmd.sh").read_text().endswith("zcut synth -o o.mcap --size 4000x4000\n")
    (o,) = fuzzlib.run_cases([fuzzlib.Case("as", "meta", "huge synth", big, timeout_s=120)], tmp_path / "w2", jobs=1,
                             as_bytes=256 << 20, runner=server)
    assert o.klass == "memory" and "resident" not in o.detail, o.detail


@pytest.mark.parametrize("mode", ["fork", "subprocess"])
def test_both_runners_run_the_real_command(tmp_path, corpus, mode, server):
    cases = [fuzzlib.Case("usage", "meta", "no such command", ["nope"]),
             fuzzlib.Case("topics", "meta", "a good log", ["topics", "--check", "w3.mcap"],
                          files={"w3.mcap": corpus["w3.mcap"]}, expect_frames=3, count="check")]
    got = {o.case.id: o for o in fuzzlib.run_cases(cases, tmp_path, jobs=2, mode=mode,
                                                   runner=server if mode == "fork" else None)}
    assert got["usage"].klass == "clean" and got["usage"].rc == 1 and got["usage"].detail.startswith("error: ")
    assert got["topics"].klass == "clean" and got["topics"].rc == 0
    assert "check: 3 frames decoded (3 with colour)" in got["topics"].stdout
