"""Every parameter reaches its kernel, in every command (docs/pipeline.md, "One config").

For every field of every stage's parameters (and the config's top-level keys), a non-default value
is set through a config file, and `zcut replay`, `accuracy`, `annotate` (the page's frames), `sweep`
and `batch` are run on the same small synthetic log with a bin model. Each command's result must
change from its result with the defaults, and agree with the replay's (the same masks' counts), or
the field is listed in :data:`UNCHANGED` with the reason it cannot change this log's result.

A field that one command honours and another ignores (a configured `connectivity = 4` that `sweep`
honoured and `replay` ignored) fails here.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json

import pyarrow.parquet as pq
import pytest
from cli_helpers import main

from replay.pipeline import config as cfg

#: section -> field -> the value set in the config file (TOML text)
VALUES: dict[str, dict[str, str]] = {
    "": {"part": '"spheres"', "parameters": '"geometry"', "methods": '["zcut"]'},
    "zcut": {"step_mm": "0.5", "max_depth_mm": "8.0", "max_area_px": "4.0", "rho_thr": "0.02",
             "a_max_px": "200.0", "connectivity": "4"},
    "sor": {"enabled": "false", "k": "9", "std_ratio": "0.3", "convention": '"open3d"', "region": '"zone"'},
    "bin_mask": {"enabled": "false", "threshold": "250.0", "dilate_px": "12", "min_area_frac": "0.95",
                 "prefer_centre": "false"},
    "registration": {"method": '"point_to_point"', "voxel_mm": "8.0", "max_correspondence_mm": "30.0",
                     "max_iterations": "1", "min_fitness": "1.0", "max_rmse_mm": "0.0001", "ring_frac": "1.0",
                     "seed_from_first_frame": "false"},
    "removal": {"delta_mm": "10.0", "rim_offset_mm": "60.0", "search_radius_mm": "10.0", "straggler_mm": "0.0",
                "straggler_neighbours": "8", "mode": '"paper"', "tolerance_mm": "6.0", "residual_quantile": "50.0",
                "residual_margin_mm": "4.0", "min_tolerance_mm": "5.0", "max_tolerance_mm": "1.0",
                "check_threshold_px": "1000000.0", "check_min_ring_px": "1000000", "check_min_rim_in_view": "1.0"},
}

#: fields that cannot change the result on this log, and why (a reason, never a silence)
UNCHANGED: dict[str, str] = {
    "bin_mask.prefer_centre": "the synthetic bin is both the largest bright component and the one covering the "
                              "image centre: preferring the centre chooses the same component",
    "bin_mask.dilate_px": "the synthetic bin's walls have no gap: the closing (dilate, fill the holes, erode back) "
                          "gives the same footprint at any radius",
    "registration.min_fitness": "the synthetic bin's rim is confirmed everywhere (fitness 1.000): no threshold "
                                "fails it",
    "removal.check_threshold_px": "the removal leaves no certain bin pixel where the filters judge on this log (the "
                                  "bin check's figure is 0 on both frames): no threshold >= 0 changes a flag",
    "removal.check_min_rim_in_view": "the whole of the bin's rim is in the camera's view on this log (share 1.0): no "
                                     "threshold <= 1 flags a frame",
}
#: fields that change only the registration's figures (fitness, RMSE) on this log, not a mask: only the
#: commands that report those figures (replay's table, batch's frames.parquet) show them
REGISTRATION_ONLY: dict[str, str] = {
    "registration.seed_from_first_frame": "the synthetic bin does not move between frames: registered from "
                                          "scratch or from the first frame's pose, frame 1 lands on the same "
                                          "pose to far below a pixel; only its RMSE moves",
}
#: registration fields whose change moves the registered pose by a fraction of a millimetre on this log:
#: the robust removal's tolerance absorbs it (docs/bin_robustness.md), so a mask changes at most by a
#: pixel at the tolerance's edge, from run to run (Open3D's ICP sums in parallel); the registration's
#: figures (fitness, RMSE), which replay's table and batch's frames.parquet report, always change
ABSORBED_BY_REMOVAL: dict[str, str] = {
    f"registration.{f}": "a pose that differs by far less than the robust tolerance removes the same bin pixels"
    for f in ("method", "voxel_mm", "max_correspondence_mm", "max_iterations")
}
#: fields a command does not read, by design (documented in docs/pipeline.md)
NOT_READ: dict[tuple[str, str], str] = {
    (f"removal.{f}", "annotate"): "the bin check flags a frame and changes no mask: the labelling page shows masks"
    for f in ("check_threshold_px", "check_min_ring_px", "check_min_rim_in_view")
}
#: the registration's float figures are compared to this many significant digits (Open3D's ICP sums in
#: parallel: the last digit of its RMSE varies from run to run, docs/studies.md)
DIGITS = 9


def _rounded(v):
    return v if not isinstance(v, float) else float(f"{v:.{DIGITS}g}")


def _fields() -> list[str]:
    out = []
    for section, fields in VALUES.items():
        out += [f"{section}.{f}" if section else f for f in fields]
    return out


def test_the_table_covers_every_field_of_every_stage():
    """A new parameter must be added to VALUES (and so to this test)."""
    want = {f"{name}.{f.name}" for name, cls in cfg.STAGE_SECTIONS.items() for f in dataclasses.fields(cls)}
    want |= {f"zcut.{k}" for k in cfg.ZCUT_INPUTS}
    want |= {k for k in cfg.TOP_KEYS if k != "preset"}  # preset = part + parameters = "geometry"
    assert set(_fields()) == want


def _config_text(field: str | None) -> str:
    if field is None:
        return "# the defaults\n"
    section, _, name = field.rpartition(".")
    value = VALUES[section][name]
    if not section:
        return f"{name} = {value}\n"
    return f"[{section}]\n{name} = {value}\n"


def _json_of(*argv) -> dict:
    """``zcut ARGV`` in this process; its stdout parsed as JSON (exit status 0 asserted)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main([str(a) for a in argv])
    assert rc == 0, argv
    return json.loads(buf.getvalue())


def _quiet(*argv) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([str(a) for a in argv]) == 0, argv


def _signatures(log, model, config, out_dir) -> dict:
    """Each command's result on the log with this config, reduced to what must agree."""
    from replay.logs.reader import LogReader

    out_dir.mkdir(parents=True, exist_ok=True)
    sig: dict = {}
    res = out_dir / "r.mcap"
    frames = _json_of("replay", log, "--bin-model", model, "--config", config, "--out", res,
                      "--json")["frames"]
    masks = {f.index: {t: m.tobytes() for t, m in sorted(f.masks.items()) if t.startswith("/zcut/")}
             for f in LogReader(res).frames()}
    sig["replay"] = ([(r["index"], r["valid_px"], r["zcut"], r["sor"], r["both"], r["above_rim"], r["clusters"],
                       _rounded(r["fitness"]), _rounded(r["rmse_mm"]), r["bin_check"], r["bin_flagged"])
                      for r in frames], masks)
    counts = {r["index"]: (r["zcut"], r["sor"]) for r in frames}

    rep = _json_of("accuracy", log, "--bin-model", model, "--config", config, "--json")
    sig["accuracy"] = json.dumps(rep["frames"], sort_keys=True)

    from replay.pipeline.bin_model import load_bin_model
    from replay.pipeline.session import ReplaySession

    # the page's frames: the log opened as annotate.server.open_page opens it, its catalogue's results
    replay = ReplaySession.open(log, config_file=config, bin_model=load_bin_model(model))
    page = {}
    for f, r in replay.results():
        page[f.index] = (r.zcut_outliers.tobytes(), r.sor_outliers.tobytes())
    sig["annotate"] = page
    for i, (z, s) in page.items():  # the page shows the replay's masks
        assert (z, s) == (masks[i]["/zcut/outliers"], masks[i].get("/zcut/sor_outliers", page[i][1]))

    b = out_dir / "batch"
    _quiet("batch", log, "--bin-model", model, "--config", config, "-o", b, "--workers", "0")
    rows = sorted(pq.read_table(b / "frames.parquet").to_pylist(), key=lambda r: r["frame"])
    sig["batch"] = [tuple(_rounded(v) for k, v in sorted(r.items()) if not (k.startswith("t_") and k.endswith("_s")))
                    for r in rows]
    for r in rows:
        assert (r["zcut"], r["sor"]) == counts[r["frame"]], "batch disagrees with replay"

    s = out_dir / "sweep"
    _quiet("sweep", log, "--bin-model", model, "--config", config, "-o", s, "--workers", "0", "--no-report")
    summary = json.loads((s / "summary.json").read_text())
    c = summary["grid"]["chosen"]
    t = pq.read_table(s / "sweep.parquet").to_pylist()
    at = sorted((r["frame"], r["method"], r["n_pred"], r["tp"], r["fp"], r["fn"]) for r in t
                if (r["method"] == "zcut" and r["step_mm"] == c["step_mm"] and r["max_depth_mm"] == c["max_depth_mm"]
                    and (r["rho_thr"] is None or abs(r["rho_thr"] - c["rho_thr"]) < 1e-12))
                or (r["method"] == "sor" and r["sor_k"] == c["sor_k"] and r["sor_std_ratio"] == c["sor_std_ratio"]
                    and r["step_mm"] in (None, c["step_mm"]) and r["max_depth_mm"] in (None, c["max_depth_mm"])))
    sig["sweep"] = (at, summary["bin_flagged"])
    for frame, method, n_pred, *_ in at:
        assert n_pred == counts[frame][0 if method == "zcut" else 1], f"sweep disagrees with replay ({method})"
    return sig


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("every_parameter")
    log, empty, model = d / "log.mcap", d / "empty.mcap", d / "bin.ply"
    assert main(["synth", "-o", str(log), "--parts", "rods", "--frames", "2", "--seed", "21",
                 "--size", "180x240"]) == 0
    assert main(["synth", "-o", str(empty), "--empty", "--frames", "2", "--seed", "3", "--size", "180x240"]) == 0
    assert main(["bin-model", str(empty), "-o", str(model)]) == 0
    return d, log, model


@pytest.fixture(scope="module")
def baseline(setup):
    d, log, model = setup
    config = d / "default.toml"
    config.write_text(_config_text(None))
    return _signatures(log, model, config, d / "base")


@pytest.mark.slow
@pytest.mark.parametrize("field", _fields())
def test_every_parameter_changes_every_command(setup, baseline, field, tmp_path):
    d, log, model = setup
    config = tmp_path / "c.toml"
    config.write_text(_config_text(field))
    got = _signatures(log, model, config, tmp_path / "field")
    changed = {cmd for cmd in got if got[cmd] != baseline[cmd]}
    if field in UNCHANGED:
        assert not changed, f"{field} changes {sorted(changed)}: remove it from UNCHANGED"
        return
    expected = {cmd for cmd in got if (field, cmd) not in NOT_READ}
    if field in REGISTRATION_ONLY:
        expected = {"replay", "batch"}
    if field in ABSORBED_BY_REMOVAL:
        assert {"replay", "batch"} <= changed, f"{field}: changes {sorted(changed)}, not the registration's figures"
        return
    assert changed == expected, (f"{field}: changes {sorted(changed)}, not {sorted(expected - changed)}"
                                 f"{''.join(f'; {c}: {NOT_READ[(field, c)]}' for c in got if (field, c) in NOT_READ)}")
