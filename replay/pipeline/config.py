"""Pipeline configuration: one frozen dataclass per stage, nested in :class:`PipelineConfig`.

Layers, later ones win: built-in defaults < the part-kind preset (paper §5.4; chosen from a
synthetic log's ``zcut.synth`` metadata or ``preset = "..."`` in the file) < the TOML file
(``--config``) < command-line overrides (``--step`` ...). Every layer is a nested dict; unknown
keys are errors. :func:`resolve` is the one place where derived defaults (the z-cut area threshold
from ρ_thr and a_max, the preset's values) are filled in; its result is written next to every
output (:func:`to_toml`) and logged to Rerun as a document.

Units follow the paper: millimetres for lengths, pixels for areas.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from replay.errors import ConfigError

SOR_CONVENTIONS = ("pcl", "open3d")
REG_METHODS = ("point_to_plane", "point_to_point")
# Without a part size or a_max, assume a part's largest face covers this fraction of the image.
DEFAULT_FACE_FRACTION = 0.01


def _num(obj: object, name: str, *, gt: float | None = None, ge: float | None = None,
         le: float | None = None, integer: bool = False, optional: bool = False) -> None:
    section = _section_name(obj)
    v = getattr(obj, name)
    if v is None and optional:
        return
    bad = isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
    if not bad and integer and int(v) != v:
        bad = True
    if not bad and ((gt is not None and not v > gt) or (ge is not None and not v >= ge)
                    or (le is not None and not v <= le)):
        bad = True
    if bad:
        rng = []
        if gt is not None:
            rng.append(f"> {gt:g}")
        if ge is not None:
            rng.append(f">= {ge:g}")
        if le is not None:
            rng.append(f"<= {le:g}")
        kind = "an integer" if integer else "a number"
        raise ConfigError(f"{section}.{name} must be {' '.join([kind, ' and '.join(rng)]).strip()}, got {v!r}")


def _section_name(obj: object) -> str:
    for name, cls in SECTIONS.items():
        if type(obj) is cls:
            return name
    return type(obj).__name__


def _bool(obj: object, name: str) -> None:
    v = getattr(obj, name)
    if not isinstance(v, bool):
        raise ConfigError(f"{_section_name(obj)}.{name} must be true or false, got {v!r}")


def _choice(obj: object, name: str, choices: tuple[str, ...]) -> None:
    v = getattr(obj, name)
    if v not in choices:
        raise ConfigError(f"{_section_name(obj)}.{name} must be one of {', '.join(choices)}, got {v!r}")


@dataclass(frozen=True, slots=True)
class BinMaskConfig:
    """RGB bin footprint (:func:`zcut.binmask.bin_mask`)."""

    enabled: bool = True
    threshold: float = 150.0
    dilate_px: int = 3
    min_area_frac: float = 0.01

    def __post_init__(self) -> None:
        _bool(self, "enabled")
        _num(self, "threshold", ge=0, le=255)
        _num(self, "dilate_px", ge=0, integer=True)
        _num(self, "min_area_frac", ge=0, le=1)


@dataclass(frozen=True, slots=True)
class RegistrationConfig:
    """ICP of the bin model (:func:`zcut.registration.register_bin`)."""

    method: str = "point_to_plane"
    voxel_mm: float = 3.0
    max_correspondence_mm: float = 10.0
    max_iterations: int = 30
    min_fitness: float = 0.3
    max_rmse_mm: float = 5.0
    use_previous: bool = True

    def __post_init__(self) -> None:
        _choice(self, "method", REG_METHODS)
        _num(self, "voxel_mm", ge=0)
        _num(self, "max_correspondence_mm", gt=0)
        _num(self, "max_iterations", ge=1, integer=True)
        _num(self, "min_fitness", ge=0, le=1)
        _num(self, "max_rmse_mm", gt=0)
        _bool(self, "use_previous")


@dataclass(frozen=True, slots=True)
class RemovalConfig:
    """Table, easy outliers and bin points (:func:`zcut.removal.remove_table_and_bin`)."""

    delta_mm: float = 0.1
    rim_offset_mm: float = 5.0
    search_radius_mm: float | None = None
    straggler_mm: float = 2.0
    straggler_neighbours: int = 3

    def __post_init__(self) -> None:
        _num(self, "delta_mm", ge=0)
        _num(self, "rim_offset_mm", ge=0)
        _num(self, "search_radius_mm", gt=0, optional=True)
        _num(self, "straggler_mm", ge=0)
        _num(self, "straggler_neighbours", ge=0, le=8, integer=True)


@dataclass(frozen=True, slots=True)
class ZCutConfig:
    """z-cut parameters (paper §3, §5.4): Δd, d_max in mm; μ_thr in px, given or ρ_thr·a_max."""

    step_mm: float = 0.2
    max_depth_mm: float = 30.0
    max_area_px: float | None = None
    rho_thr: float = 0.07
    a_max_px: float | None = None
    connectivity: int = 8

    def __post_init__(self) -> None:
        _num(self, "step_mm", gt=0)
        _num(self, "max_depth_mm", gt=0)
        _num(self, "max_area_px", gt=0, optional=True)
        _num(self, "rho_thr", gt=0)
        _num(self, "a_max_px", gt=0, optional=True)
        if self.connectivity not in (4, 8) or isinstance(self.connectivity, bool):
            raise ConfigError(f"zcut.connectivity must be 4 or 8, got {self.connectivity!r}")


@dataclass(frozen=True, slots=True)
class SorConfig:
    """Statistical outlier removal (:func:`zcut.sor.sor_outliers`), the paper's comparison."""

    enabled: bool = True
    k: int = 4
    std_ratio: float = 1.0
    convention: str = "pcl"

    def __post_init__(self) -> None:
        _bool(self, "enabled")
        _num(self, "k", ge=1, integer=True)
        _num(self, "std_ratio", ge=0)
        _choice(self, "convention", SOR_CONVENTIONS)


SECTIONS: dict[str, type] = {
    "bin_mask": BinMaskConfig,
    "registration": RegistrationConfig,
    "removal": RemovalConfig,
    "zcut": ZCutConfig,
    "sor": SorConfig,
}


@dataclass(frozen=True, slots=True)
class PipelineConfig:
    """The whole pipeline's configuration.

    Attributes
    ----------
    preset : str or None
        The part-kind preset the values were derived from (``replay.synth.PART_KINDS`` key).
    """

    bin_mask: BinMaskConfig = field(default_factory=BinMaskConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    removal: RemovalConfig = field(default_factory=RemovalConfig)
    zcut: ZCutConfig = field(default_factory=ZCutConfig)
    sor: SorConfig = field(default_factory=SorConfig)
    preset: str | None = None

    def __post_init__(self) -> None:
        for name, cls in SECTIONS.items():
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"PipelineConfig.{name} must be a {cls.__name__}, got {getattr(self, name)!r}")
        if self.preset is not None and not isinstance(self.preset, str):
            raise ConfigError(f"PipelineConfig.preset must be a string, got {self.preset!r}")


# ----------------------------------------------------------------------------------- dict layers


def to_dict(config: PipelineConfig) -> dict[str, Any]:
    """Nested dict of the config, ``None`` values left out (TOML has no null)."""
    out: dict[str, Any] = {}
    if config.preset is not None:
        out["preset"] = config.preset
    for name in SECTIONS:
        sec = getattr(config, name)
        out[name] = {f.name: getattr(sec, f.name) for f in dataclasses.fields(sec)
                     if getattr(sec, f.name) is not None}
    return out


def merge(base: dict[str, Any], *layers: dict[str, Any], source: str = "config") -> dict[str, Any]:
    """Deep-merge layers of nested dicts; unknown sections or keys raise :class:`ConfigError`."""
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    for layer in layers:
        for key, value in layer.items():
            if key == "preset":
                if value is not None and not isinstance(value, str):
                    raise ConfigError(f"{source}: preset must be a string, got {value!r}")
                out["preset"] = value
                continue
            if key not in SECTIONS:
                raise ConfigError(f"{source}: unknown section [{key}] (known: {', '.join(SECTIONS)}, preset)")
            if not isinstance(value, dict):
                raise ConfigError(f"{source}: [{key}] must be a table, got {value!r}")
            names = {f.name for f in dataclasses.fields(SECTIONS[key])}
            for k in value:
                if k not in names:
                    raise ConfigError(f"{source}: unknown key {key}.{k} (known: {', '.join(sorted(names))})")
            out.setdefault(key, {}).update(value)
    return out


def from_dict(d: dict[str, Any], *, source: str = "config") -> PipelineConfig:
    """Build a config from a nested dict (missing keys take the defaults)."""
    d = merge({}, d, source=source)
    try:
        sections = {name: cls(**d.get(name, {})) for name, cls in SECTIONS.items()}
        return PipelineConfig(**sections, preset=d.get("preset"))
    except ConfigError as e:
        raise ConfigError(f"{source}: {e}") from None


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML config file as a validated layer (nested dict)."""
    p = Path(path)
    try:
        with p.open("rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{p}: not valid TOML: {e}") from e
    merge({}, data, source=str(p))
    from_dict(data, source=str(p))  # validates values early, naming the file
    return data


def cli_layer(*, step: float | None = None, max_depth: float | None = None,
              max_area: float | None = None, preset: str | None = None) -> dict[str, Any]:
    """The ``--step/--max-depth/--max-area/--preset`` overrides as a layer."""
    out: dict[str, Any] = {} if preset is None else {"preset": preset}
    z: dict[str, Any] = {}
    if step is not None:
        z["step_mm"] = float(step)
    if max_depth is not None:
        z["max_depth_mm"] = float(max_depth)
    if max_area is not None:
        z["max_area_px"] = float(max_area)
    if z:
        out["zcut"] = z
    return out


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return json.dumps(v)
    raise TypeError(f"cannot write {v!r} to TOML")


def to_toml(config: PipelineConfig, *, header: str = "") -> str:
    """The config as TOML text that :func:`load_toml` reads back to the same config."""
    d = to_dict(config)
    lines = [f"# {line}" for line in header.splitlines()] if header else []
    if "preset" in d:
        lines.append(f"preset = {_toml_value(d['preset'])}")
    for name in SECTIONS:
        lines.append("")
        lines.append(f"[{name}]")
        for k, v in d[name].items():
            lines.append(f"{k} = {_toml_value(v)}")
    return "\n".join(lines).lstrip("\n") + "\n"


# ----------------------------------------------------------------------------------- resolution


@dataclass(frozen=True, slots=True)
class Resolved:
    """A resolved config and what the resolution decided, for the user to read."""

    config: PipelineConfig
    notes: tuple[str, ...]


def preset_layer(part_kind: str, *, camera_distance_mm: float | None = None,
                 fx: float | None = None, fy: float | None = None) -> dict[str, Any]:
    """The z-cut values of a synthetic part kind, derived per paper §5.4.

    ``zcut.params.ZCutParams.from_geometry`` (Δd = 0.02·p_min, d_max = 3·p_min clipped into
    [p_min, 0.7·b_h]) and ``a_max_from_camera`` (the part's largest face in pixels at the camera
    distance); μ_thr = ρ_thr·a_max follows in :func:`resolve`.
    """
    from replay.presets import BIN, PART_KINDS
    from zcut.params import ZCutParams, a_max_from_camera

    if part_kind not in PART_KINDS:
        raise ConfigError(f"preset must be one of {', '.join(PART_KINDS)}, got {part_kind!r}")
    kind = PART_KINDS[part_kind]
    a_max = None
    if camera_distance_mm is not None and fx is not None and fy is not None:
        a_max = a_max_from_camera(kind.face_area_mm2, distance_mm=camera_distance_mm, fx_px=fx, fy_px=fy)
    # Δd and d_max do not depend on a_max; without a camera only they are taken from the preset.
    p = ZCutParams.from_geometry(p_min_mm=kind.p_min_mm, bin_height_mm=BIN.height_mm,
                                 a_max_px=1.0 if a_max is None else a_max)
    z: dict[str, Any] = {"step_mm": float(p.step), "max_depth_mm": float(p.max_depth)}
    if a_max is not None:
        z["a_max_px"] = float(a_max)
    return {"preset": part_kind, "zcut": z}


def resolve(
    *,
    file_layer: dict[str, Any] | None = None,
    cli: dict[str, Any] | None = None,
    part_kind: str | None = None,
    camera_distance_mm: float | None = None,
    fx: float | None = None,
    fy: float | None = None,
    image_shape: tuple[int, int] | None = None,
) -> Resolved:
    """The one function that fills in derived defaults.

    Parameters
    ----------
    file_layer : dict, optional
        From :func:`load_toml`. A ``preset`` key there beats ``part_kind``.
    cli : dict, optional
        From :func:`cli_layer`; its ``preset`` beats the file's.
    part_kind : str, optional
        From the log's ``zcut.synth`` metadata.
    camera_distance_mm, fx, fy : float, optional
        The camera, for a_max of the preset's part.
    image_shape : (H, W), optional
        For the fallback a_max when nothing else gives one.

    Returns
    -------
    Resolved
        ``config.zcut.max_area_px`` is always set.
    """
    file_layer = file_layer or {}
    cli = cli or {}
    notes: list[str] = []
    if cli.get("preset") is not None:
        kind, src = cli["preset"], "the command line"
    elif file_layer.get("preset") is not None:
        kind, src = file_layer["preset"], "the config file"
    else:
        kind, src = part_kind, "the log's zcut.synth metadata"
    layers: list[dict[str, Any]] = []
    if kind is not None:
        layers.append(preset_layer(kind, camera_distance_mm=camera_distance_mm, fx=fx, fy=fy))
        notes.append(f"using the {kind!r} preset (part kind from {src})")
        if camera_distance_mm is None or fx is None or fy is None:
            notes.append("the preset's a_max needs the camera distance and intrinsics: not known here")
    d = merge(to_dict(PipelineConfig()), *layers, file_layer, cli)
    z = d["zcut"]
    if "max_area_px" not in z or z["max_area_px"] is None:
        a_max = z.get("a_max_px")
        if a_max is None and image_shape is not None:
            a_max = DEFAULT_FACE_FRACTION * image_shape[0] * image_shape[1]
            z["a_max_px"] = float(a_max)
            notes.append(f"no part size known: a_max = {DEFAULT_FACE_FRACTION:.0%} of the image = "
                         f"{a_max:.0f} px (set zcut.a_max_px or --max-area)")
        if a_max is None:
            raise ConfigError("zcut.max_area_px cannot be derived: give max_area_px, a_max_px or a preset")
        z["max_area_px"] = float(z["rho_thr"]) * float(a_max)
    config = from_dict(d, source="resolved config")
    zc = config.zcut
    notes.append(f"z-cut: step {zc.step_mm:g} mm, max depth {zc.max_depth_mm:g} mm, "
                 f"max area {zc.max_area_px:.1f} px")
    return Resolved(config, tuple(notes))
