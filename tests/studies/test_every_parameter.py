"""Every parameter reaches its kernel, in every command (docs/pipeline.md, "One config").

For every field of every stage's parameters (and the config's top-level keys), a non-default value
is set through a config file, and `zcut replay`, `accuracy`, `annotate` (the page's frames), `sweep`
and `batch` are run on the same small synthetic log with a bin model (the `explained` fields on a log
of :data:`OWN_FRAMES` frame: each command fits the part model on every frame). Each command's result
must change from its result with the defaults, and agree with the replay's (the same masks' counts),
or the field is listed in :data:`UNCHANGED` with the reason it cannot change this log's result.

A field that one command honours and another ignores (a configured `connectivity = 4` that `sweep`
honoured and `replay` ignored) fails here.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import hashlib
import io
import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import main, synth_log, synth_with_bin_model

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
                "straggler_neighbours": "8", "straggler_bound": '"global"', "mode": '"paper"', "tolerance_mm": "6.0", "residual_quantile": "50.0",
                "residual_margin_mm": "4.0", "min_tolerance_mm": "5.0", "max_tolerance_mm": "1.0",
                "check_threshold_px": "1000000.0", "check_min_ring_px": "1000000", "check_min_rim_in_view": "1.0"},
    "radius": {"radius_mm": "6.0", "min_points": "2"},
    "cluster": {"max_neighbour_mm": "5.0", "min_area_mm2": "500.0", "connectivity": "4"},
    "speckle": {"max_diff_mm": "5.0", "max_size_px": "1000"},
    "window": {"min_inliers": "7", "rel_tolerance": "0.0005"},
    "mixed_pixel": {"min_angle_deg": "30.0"},
    "suspects": {"min_residual_mm": "5.0", "noise_k": "20.0", "jump_mm": "50.0", "below_min_directions": "1",
                 "fill_iterations": "0", "floating_step_mm": "20.0", "floating_rho": "0.07", "plain_rho": "0.0",
                 "evidence_holes": "0.0", "evidence_inconsistent": "1.0", "evidence_ring_valid": "0.0",
                 "a_max": "20.0", "merge_radius_px": "0", "max_groups": "5"},
    "stereo_uniqueness": {"uniqueness_ratio": "25"},
    "stereo_lr": {"disp12_max_diff": "0"},
    "stereo_speckle": {"speckle_window": "400", "speckle_range": "1"},
    "stereo_texture": {"texture_threshold": "800"},
    "zcut_top": {"top_faces": "20.0"},
    "explained": {"k": "1.0", "err_floor_mm": "3.0", "part_model": '"{part_mesh}"', "part_model_unit": '"m"',
                  "fit_max_err_mm": "0.01", "fit_min_support": "1.0", "fit_max_overlap": "1.0"},
}
#: sections whose method runs with a methods list of its own (the base values are the defaults): its
#: fields are compared with the defaults of that same list
OWN: dict[str, str] = {"explained": 'methods = ["zcut", "sor", "explained"]\n'}
#: the log the OWN sections run on: one frame (each command fits the part model on every frame, ~1 CPU s a
#: frame and command), of a seed whose frame shows every field's change (seed 21's first frame shows no
#: change of explained.fit_max_overlap: only its second frame has overlapping fits)
OWN_FRAMES, OWN_SEED = 1, 24
#: the sections of methods that run only when the methods list names them: their fields are set with
#: every method named, and compared with the defaults of that same list
BANK = ("radius", "cluster", "speckle", "window", "mixed_pixel", "suspects", "zcut_top")
BANK_METHODS = 'methods = ["zcut", "sor", ' + ", ".join(f'"{m}"' for m in BANK) + "]\n"
#: the bank's base values on this log (its defaults are for 1920 × 1200 frames: at 180 × 240 a pixel
#: covers ~2.5 mm and the default radius, cluster and speckle flag the whole zone, which no single
#: field can change); each field is set over these, and compared with these
BANK_BASE: dict[str, dict[str, str]] = {
    "radius": {"radius_mm": "8.0", "min_points": "4"},
    "cluster": {"max_neighbour_mm": "10.0"},
    "speckle": {"max_diff_mm": "10.0"},
    # a low noise factor lets the residual floors decide; with the holes and ring tests failing every
    # component, the roughness test and the plain area decide which floating components are suspects
    "suspects": {"noise_k": "1.0", "evidence_holes": "1.0", "evidence_ring_valid": "1.0"},
}

#: fields that cannot change the result on this log, and why (a reason, never a silence)
UNCHANGED: dict[str, str] = {
    "removal.straggler_bound": "no straggler of this small log lies beyond 3 of the bin's Err (the bound gives no "
                               "pixel back); tests/zcut/test_removal_straggler_bound.py moves wall pixels beyond it "
                               "and checks each setting's result, the removal's parameters reaching every command as "
                               "one RemovalParams",
    "registration.seed_from_first_frame": "the synthetic bin does not move between frames: frame 0's pose is the "
                                          "seed itself, and frame 1, registered from scratch or from frame 0's "
                                          "pose, converges to the same pose (fitness and RMSE equal to 9 digits); "
                                          "tests/replay/pipeline/test_stages.py checks that the seed starts the "
                                          "registration, and does not when off",
    "suspects.merge_radius_px": "it groups the suspects for review (docs/filters.md, Groups): the suspect mask, "
                                "which the commands score, is the detectors' union whatever the grouping",
    "suspects.max_groups": "it bounds the number of review groups (docs/filters.md, Groups): the suspect mask, "
                           "which the commands score, is the detectors' union whatever the grouping",
    "bin_mask.prefer_centre": "the synthetic bin is both the largest bright component and the one covering the "
                              "image centre: preferring the centre chooses the same component",
    "bin_mask.dilate_px": "the synthetic bin's walls have no gap: the closing (dilate, fill the holes, erode back) "
                          "gives the same footprint at any radius",
    **{f"{section}.{f}": "a stereo post-filter's strength selects one of the masks `zcut record-stereo` recorded "
                         "(/stereo/rejected/...); this synthetic log holds none, so every strength scores nothing; "
                         "tests/cli/test_record_stereo_rejected.py checks that accuracy and sweep score the mask "
                         "each strength names"
       for section in ("stereo_uniqueness", "stereo_lr", "stereo_speckle", "stereo_texture")
       for f in VALUES[section]},
    "registration.min_fitness": "the synthetic bin's rim is confirmed everywhere (fitness 1.000): no threshold "
                                "fails it",
    "removal.check_threshold_px": "the removal leaves no certain bin pixel where the filters judge on this log (the "
                                  "bin check's figure is 0 on both frames): no threshold >= 0 changes a flag",
    "removal.check_min_rim_in_view": "the whole of the bin's rim is in the camera's view on this log (share 1.0): no "
                                     "threshold <= 1 flags a frame",
    "explained.part_model_unit": "it states the unit of a mesh file given as explained.part_model; the log's own "
                                 "part_model.ply, used when none is given, states its unit in its header",
}
#: fields that change only the registration's figures (fitness, RMSE) on this log, not a mask: only the
#: commands that report those figures (replay's table, batch's frames.parquet) show them
REGISTRATION_ONLY: dict[str, str] = {}
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
} | {
    (f"{section}.{f}", "annotate"): "the labelling page's candidates are the z-cut's and SOR's clusters "
                                    "(docs/filters.md, \"In the pipeline\"): the bank's masks are not on the page"
    for section in (*BANK, *OWN) for f in VALUES[section]
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
    want = {f"{name}.{f.name}" for name, cls in cfg.stage_sections().items() for f in dataclasses.fields(cls)}
    want |= {f"zcut.{k}" for k in cfg.ZCUT_INPUTS}
    want |= {k for k in cfg.TOP_KEYS if k != "preset"}  # preset = part + parameters = "geometry"
    assert set(_fields()) == want


def _config_text(field: str | None, *, bank: bool = False, own: str | None = None) -> str:
    section, _, name = field.rpartition(".") if field is not None else ("", "", "")
    if own is not None:
        return OWN[own] + ("" if field is None else f"[{section}]\n{name} = {VALUES[section][name]}\n")
    if not bank:
        if field is None:
            return "# the defaults\n"
        value = VALUES[section][name]
        return f"{name} = {value}\n" if not section else f"[{section}]\n{name} = {value}\n"
    tables = {k: dict(v) for k, v in BANK_BASE.items()}
    if field is not None:
        tables.setdefault(section, {})[name] = VALUES[section][name]
    return BANK_METHODS + "".join(f"[{sec}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items())
                                  for sec, kv in tables.items())


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
             for f in LogReader(res, cloudless=True).frames()}
    sig["replay"] = ([(r["index"], r["valid_px"], r["zcut"], r["sor"], r["both"], r["above_rim"], r["clusters"],
                       _rounded(r["fitness"]), _rounded(r["rmse_mm"]), r["bin_check"], r["bin_flagged"],
                       *(r.get(m) for m in (*BANK, *OWN))) for r in frames], masks)
    counts = {r["index"]: (r["zcut"], r["sor"]) for r in frames}
    bank_counts = {(r["index"], m): r[m] for r in frames for m in (*BANK, *OWN) if m in r}

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
        for m in (*BANK, *OWN):
            if (r["frame"], m) in bank_counts:
                assert r[m] == bank_counts[(r["frame"], m)], f"batch disagrees with replay ({m})"

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
    at += sorted((r["frame"], r["method"], r["n_pred"], r["tp"], r["fp"], r["fn"]) for r in t
                 if r["method"] in (*BANK, *OWN))
    sig["sweep"] = (at, summary["bin_flagged"])
    for frame, method, n_pred, *_ in at:
        want = bank_counts[(frame, method)] if method in (*BANK, *OWN) else counts[frame][0 if method == "zcut" else 1]
        assert n_pred == want, f"sweep disagrees with replay ({method})"
    return sig


def _digest(a) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(f"{a.dtype}{a.shape}".encode() + a.tobytes()).hexdigest()


@pytest.fixture(scope="module", autouse=True)
def fits_once():
    """``zcut.fits.fit_prepared`` (the part fits, most of an ``explained`` command's time) computed once per
    distinct call in this module: the five commands of a field each fit the same frame with the same arguments.
    The key is every argument: the cloud's and the zone's bytes, the prepared model (the same object while its
    file is unchanged: ``replay.pipeline.explained`` reads it once per file version; kept alive here), the
    intrinsics and the ``FitParams``. A command that passed another value of a field calls with other
    arguments and gets its own fits, as before; every call made with the same arguments gets the fits the first
    one computed (each its own deep copy), which is what the deterministic ``fit_prepared`` returns again
    (tests/zcut/fits/ check it and its digests)."""
    import zcut.fits

    real = zcut.fits.fit_prepared
    memo: dict = {}

    def fit_prepared(xyz_mm, zone, model, *, intrinsics=None, params=None):
        key = (_digest(xyz_mm), _digest(zone), id(model), None if intrinsics is None else tuple(intrinsics),
               params)
        if key not in memo:
            memo[key] = (model, real(xyz_mm, zone, model, intrinsics=intrinsics, params=params))
        return copy.deepcopy(memo[key][1])

    with pytest.MonkeyPatch.context() as m:
        m.setattr(zcut.fits, "fit_prepared", fit_prepared)
        yield memo


@pytest.fixture(scope="module", autouse=True)
def prepared_once():
    """``replay.pipeline.bin_model.prepared_bin_model`` (the bin model's search structures, which every command's
    session reads back from the cache folder: ~0.07 CPU s, four sessions a field) made or read once per distinct
    call in this module, keyed as the cache folder keys it: the model's points, normals and spacing, and the
    registration's and removal's parameters (their repr). A command that passed another registration or removal
    value gets its own, as before; the read-back equals the preparation bit for bit
    (tests/replay/pipeline/test_bin_model_cache.py), and the pipeline only reads a prepared model (a session's
    frames in flight share one)."""
    from replay.pipeline import bin_model as bm

    real = bm.prepared_bin_model
    memo: dict = {}

    def prepared_bin_model(model, *, registration, removal):
        key = (_digest(model.points), None if model.normals is None else _digest(model.normals),
               repr(float(model.spacing_m)), repr(registration), repr(removal))
        if key not in memo:
            memo[key] = real(model, registration=registration, removal=removal)
        return memo[key]

    with pytest.MonkeyPatch.context() as m:
        m.setattr(bm, "prepared_bin_model", prepared_bin_model)
        yield memo


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("every_parameter")
    log, _, model = synth_with_bin_model(d, parts="rods", seed=21, size="180x240")
    # the OWN sections' log
    synth_log(d / "own.mcap", parts="rods", frames=OWN_FRAMES, seed=OWN_SEED, size="180x240")
    _ball_mesh(d / "ball.stl")  # another part's mesh: explained.part_model
    return d, log, model


def _ball_mesh(path) -> None:
    import open3d as o3d

    o3d.io.write_triangle_mesh(str(path), o3d.geometry.TriangleMesh.create_sphere(radius=8.0).compute_triangle_normals())


@pytest.fixture(scope="module")
def own_baseline(setup):
    d, log, model = setup
    config = d / "explained.toml"
    config.write_text(_config_text(None, own="explained"))
    return _signatures(d / "own.mcap", model, config, d / "explained")


@pytest.fixture(scope="module")
def baseline(setup):
    d, log, model = setup
    config = d / "default.toml"
    config.write_text(_config_text(None))
    return _signatures(log, model, config, d / "base")


@pytest.fixture(scope="module")
def bank_baseline(setup):
    d, log, model = setup
    config = d / "bank.toml"
    config.write_text(_config_text(None, bank=True))
    return _signatures(log, model, config, d / "bank")


@pytest.mark.slow
@pytest.mark.parametrize("field", _fields())
def test_every_parameter_changes_every_command(setup, request, field, tmp_path):
    d, log, model = setup
    section = field.partition(".")[0]
    bank = section in BANK
    own = section if section in OWN else None
    baseline = request.getfixturevalue("own_baseline" if own else "bank_baseline" if bank else "baseline")
    config = tmp_path / "c.toml"
    config.write_text(_config_text(field, bank=bank, own=own).replace("{part_mesh}", str(d / "ball.stl")))
    got = _signatures(d / "own.mcap" if own else log, model, config, tmp_path / "field")
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
