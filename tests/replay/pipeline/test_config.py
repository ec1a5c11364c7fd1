"""The pipeline config: validation, TOML layers, CLI overrides, resolution and presets."""

from __future__ import annotations

import tomllib

import pytest

from replay.pipeline import config as cfg
from replay.pipeline.config import ConfigError, LogFacts
from zcut.cloud import Intrinsics

NO_FACTS = LogFacts(None, None, None, (100, 200))


def facts(part=None, distance=None, fx=None, fy=None, shape=(100, 200)) -> LogFacts:
    K = None if fx is None else Intrinsics(fx=fx, fy=fy, cx=shape[1] / 2, cy=shape[0] / 2, width=shape[1],
                                           height=shape[0])
    return LogFacts(part, distance, K, shape, {"part": "the log's zcut.synth metadata"} if part else {})


def test_defaults_are_the_papers_nominal_values():
    c = cfg.resolve(NO_FACTS).config
    assert (c.zcut.step, c.zcut.max_depth, c.zcut.rho_thr) == (0.2, 30.0, pytest.approx(0.07))
    assert c.parameters == "nominal"
    assert c.removal.delta_mm == 0.1
    assert (c.sor.k, c.sor.std_ratio, c.sor.convention, c.sor.region) == (4, 1.0, "pcl", "top")


@pytest.mark.parametrize("section, kw, match", [
    ("zcut", {"step_mm": 0.0}, r"zcut\.step_mm must be a number > 0, got 0"),
    ("zcut", {"max_depth_mm": -1}, r"zcut\.max_depth_mm .* got -1"),
    ("zcut", {"max_area_px": float("nan")}, r"zcut\.max_area_px .* got nan"),
    ("zcut", {"connectivity": 6}, r"zcut\.connectivity must be 4 or 8, got 6"),
    ("zcut", {"step_mm": "0.2"}, r"zcut\.step_mm .* got '0\.2'"),
    ("sor", {"k": 2.5}, r"sor\.k must be an integer >= 1, got 2\.5"),
    ("sor", {"convention": "matlab"}, r"sor\.convention must be one of pcl, open3d, got 'matlab'"),
    ("sor", {"enabled": 1}, r"sor\.enabled must be true or false, got 1"),
    ("bin_mask", {"threshold": 256}, r"bin_mask\.threshold .* <= 255, got 256"),
    ("registration", {"method": "ndt"}, r"registration\.method must be one of"),
    ("registration", {"min_fitness": 1.5}, r"registration\.min_fitness"),
    ("removal", {"delta_mm": -0.1}, r"removal\.delta_mm .* got -0\.1"),
])
def test_bad_values_name_field_and_value(section, kw, match):
    with pytest.raises(ConfigError, match=match):
        cfg.sections()[section](**kw)
    with pytest.raises(ConfigError, match=match):
        cfg.check_layer({section: kw}, source="config")


def test_config_error_is_a_value_error():
    with pytest.raises(ValueError):
        cfg.sections()["zcut"](step_mm=-1.0)


@pytest.mark.parametrize("text, match", [
    ("[zcut]\nstep = 0.2\n", r"unknown key zcut\.step \(known: .*step_mm"),
    ("[zcutt]\nstep_mm = 0.2\n", r"unknown section \[zcutt\]"),
    ("zcut = 3\n", r"\[zcut\] must be a table"),
    ("[zcut]\nstep_mm = -0.2\n", r"cfg\.toml: .*zcut\.step_mm must be a number > 0, got -0\.2"),
    ("[zcut\nstep_mm = 1\n", r"cfg\.toml: not valid TOML"),
    ("preset = 3\n", r"preset must be a string"),
    ("part = \"bolts\"\n", r"part must be one of .*got 'bolts'"),
    ("parameters = \"tuned\"\n", r"parameters must be one of nominal, geometry"),
    ("[zcut]\nrho_thr = 0.07\nmax_area_px = 5\n", r"max_area_px or zcut\.rho_thr, not both"),
    ("[zcut]\nrho_thr = 1.5\n", r"zcut\.rho_thr must be a number > 0 and <= 1, got 1\.5"),
    ("[sor]\nregion = \"all\"\n", r"sor\.region must be one of top, zone"),
])
def test_toml_errors_name_the_file_and_key(tmp_path, text, match):
    p = tmp_path / "cfg.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match):
        cfg.load_toml(p)


def test_toml_errors_of_a_binary_or_deep_file(tmp_path):
    b = tmp_path / "bin.toml"
    b.write_bytes(bytes(range(256)))
    with pytest.raises(ConfigError, match=r"bin\.toml: not a text file"):
        cfg.load_toml(b)
    d = tmp_path / "deep.toml"
    d.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ConfigError, match=r"deep\.toml: not valid TOML"):
        cfg.load_toml(d)


def test_toml_of_a_special_or_huge_file_is_refused_without_reading_it_all(tmp_path):
    """Fuzz: ``bin-model --config /dev/zero`` read without end (killed at 3 GB)."""
    import os

    with pytest.raises(ConfigError, match="/dev/zero: not a regular file"):
        cfg.load_toml("/dev/zero")
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match=r"pipe\.toml: not a regular file"):
        cfg.load_toml(fifo)  # no writer: reading would block forever
    with pytest.raises(ConfigError, match="is a directory"):
        cfg.load_toml(tmp_path)
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (1 << 21) + "\n")
    with pytest.raises(ConfigError, match=r"big\.toml: too large for a config file"):
        cfg.load_toml(big)


def test_toml_round_trip(tmp_path):
    c = cfg.from_dict({"zcut": {"step_mm": 0.3, "max_area_px": 123.5}, "sor": {"convention": "open3d"},
                       "removal": {"search_radius_mm": 2.0}, "bin_mask": {"enabled": False}})
    text = cfg.to_toml(c, header="a header\nsecond line")
    assert text.startswith("# a header\n# second line\n")
    p = tmp_path / "c.toml"
    p.write_text(text)
    assert cfg.from_dict(cfg.load_toml(p)) == c
    assert tomllib.loads(text)["zcut"]["max_area_px"] == 123.5


def test_layers_file_beats_defaults_and_cli_beats_file(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[zcut]\nstep_mm = 0.5\nmax_depth_mm = 20.0\nmax_area_px = 40\n")
    r = cfg.resolve(NO_FACTS, file_layer=cfg.load_toml(p), cli=cfg.cli_layer(step=0.25))
    z = r.config.zcut
    assert (z.step, z.max_depth, z.max_area) == (0.25, 20.0, 40)
    assert r.config.sor == cfg.SorParams()


def test_max_area_is_derived_from_rho_and_a_max():
    r = cfg.resolve(NO_FACTS, file_layer={"zcut": {"a_max_px": 1000.0, "rho_thr": 0.05}})
    assert r.config.zcut.max_area == pytest.approx(50.0)


def test_the_later_layer_decides_between_max_area_and_rho():
    file_layer = {"zcut": {"a_max_px": 1000.0, "max_area_px": 40.0}}
    assert cfg.resolve(NO_FACTS, file_layer=file_layer).config.zcut.max_area == 40.0
    r = cfg.resolve(NO_FACTS, file_layer=file_layer, cli=cfg.cli_layer(rho=0.05))
    assert r.config.zcut.max_area == pytest.approx(50.0)


def test_fallback_a_max_from_image_size_is_announced():
    r = cfg.resolve(NO_FACTS)
    assert r.config.zcut.a_max == pytest.approx(200.0)
    assert r.config.zcut.max_area == pytest.approx(0.07 * 200.0)
    assert any("no part known" in n for n in r.notes)


def test_geometry_parameters_need_a_part():
    with pytest.raises(ConfigError, match="needs the part kind"):
        cfg.resolve(NO_FACTS, cli=cfg.cli_layer(parameters="geometry"))


def test_cli_layer_only_sets_what_was_given():
    assert cfg.cli_layer() == {}
    assert cfg.cli_layer(max_area=12) == {"zcut": {"max_area_px": 12.0}}


@pytest.mark.parametrize("kind", ["spheres", "zinc_nuts", "rods", "black_screws", "black_nuts", "sprockets"])
def test_geometry_parameters_follow_section_5_4(kind):
    from replay.presets import BIN, PART_KINDS

    part = PART_KINDS[kind]
    fx = fy = 2000.0
    dist = 450.0
    r = cfg.resolve(facts(kind, dist, fx, fy), cli=cfg.cli_layer(parameters="geometry"))
    z = r.config.zcut
    assert (r.config.part, r.config.parameters) == (kind, "geometry")
    assert 0.01 * part.p_min_mm <= z.step <= 0.04 * part.p_min_mm
    assert part.p_min_mm - 1e-9 <= z.max_depth <= max(0.7 * BIN.height_mm, part.p_min_mm) + 1e-9
    a_max = part.face_area_mm2 * fx * fy / dist**2
    assert z.a_max == pytest.approx(a_max)
    assert z.max_area == pytest.approx(0.07 * a_max)
    assert any(kind in n and "metadata" in n for n in r.notes)
    assert any("§5.4" in n for n in r.notes)


@pytest.mark.parametrize("kind", ["spheres", "rods"])
def test_a_synthetic_log_gets_the_nominal_parameters_with_its_part_a_max(kind):
    from replay.presets import PART_KINDS

    r = cfg.resolve(facts(kind, 450.0, 2000.0, 2000.0))
    z = r.config.zcut
    assert (z.step, z.max_depth) == (0.2, 30.0) and r.config.parameters == "nominal"
    assert z.a_max == pytest.approx(PART_KINDS[kind].face_area_mm2 * 2000.0**2 / 450.0**2)
    assert any("nominal" in n for n in r.notes)


def test_preset_in_the_file_beats_the_metadata_and_file_values_beat_the_preset():
    r = cfg.resolve(facts("spheres", 450.0, 1000.0, 1000.0),
                    file_layer={"preset": "rods", "zcut": {"step_mm": 0.5}})
    assert r.config.part == "rods" and r.config.parameters == "geometry" and r.config.zcut.step == 0.5
    assert any("config file" in n for n in r.notes)


def test_unknown_preset():
    with pytest.raises(ConfigError, match="preset must be one of .*got 'bolts'"):
        cfg.cli_layer(preset="bolts")


def test_the_notes_say_where_each_zcut_value_came_from(tmp_path):
    """Issue 35 #17: --step or a tuned config's d_max are not "the paper's nominal values"."""
    p = tmp_path / "tuned.toml"
    p.write_text("[zcut]\nmax_depth_mm = 60.0\n")
    r = cfg.resolve(NO_FACTS, file_layer=cfg.load_toml(p))
    assert not any("nominal values" in n for n in r.notes), r.notes
    assert "z-cut Δd = 0.2 mm (the paper's nominal value), d_max = 60 mm (zcut.max_depth_mm, the config file)" \
        in r.notes
    r = cfg.resolve(NO_FACTS, file_layer=cfg.load_toml(p), cli=cfg.cli_layer(step=0.1, rho=0.05))
    assert "z-cut Δd = 0.1 mm (--step, the command line), d_max = 60 mm (zcut.max_depth_mm, the config file)" \
        in r.notes
    assert any(n.startswith("μ_thr = ρ_thr · a_max = 0.05 × ") and n.endswith("(ρ_thr: --rho, the command line)")
               for n in r.notes), r.notes
    r = cfg.resolve(NO_FACTS, file_layer={"zcut": {"a_max_px": 1000.0, "max_area_px": 40.0}})
    assert "a_max = 1000 px (given: zcut.a_max_px, the config file)" in r.notes
    assert "μ_thr = 40 px (given: zcut.max_area_px, the config file)" in r.notes
    r = cfg.resolve(facts(part="rods"), cli={**cfg.cli_layer(max_depth=12.0), "parameters": "geometry"})
    assert any(n.startswith("z-cut Δd = ") and "(0.02·p_min of rods, paper §5.4)" in n
               and n.endswith("d_max = 12 mm (--max-depth, the command line)") for n in r.notes), r.notes


def test_the_notes_of_the_defaults_are_unchanged():
    r = cfg.resolve(NO_FACTS)
    assert "z-cut Δd and d_max: the paper's nominal values (0.2 mm, 30 mm)" in r.notes
    assert any(n.endswith("(ρ_thr: the paper's nominal value)") for n in r.notes)
