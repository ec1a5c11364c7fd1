"""Pipeline configuration: the stage parameters of :mod:`zcut.params`, nested in one
:class:`PipelineConfig`, and the one function that resolves them for a log.

Layers, later ones win: built-in defaults (the paper's nominal z-cut parameters, docs/filters.md) < the
TOML file (``--config``) < command-line overrides (``--step`` ...). Every layer is a nested dict
with the TOML file's keys; unknown keys are errors. :func:`resolve` is the one place where
derived values are filled in (the z-cut's area threshold μ_thr = ρ_thr · a_max, a_max from the
part's geometry and the camera, the §5.4 geometry-derived Δd and d_max when asked for); every
command calls it, so that ``zcut replay``, ``accuracy``, ``annotate``, ``sweep`` and ``batch`` run
the same filter on a log (docs/accuracy.md, "Same filter everywhere"). Its result is written next to every
output (:func:`to_toml`) and logged to Rerun as a document, with notes saying where each derived
value came from.

The sections are the pipeline's own (``bin_mask``, ``registration``, ``removal``), then one per method
of the registry (:mod:`replay.pipeline.methods`: ``zcut``, ``sor`` and the filter bank), in its order:
:func:`section_names`, :func:`stage_sections` and :func:`bank_sections` are views of the registry, and
the bank's parameters live in :attr:`PipelineConfig.bank` (read as ``config.radius``).

Units follow the paper and the config file: millimetres for lengths, pixels for areas. The stage
types hold the same fields as the file's keys (the z-cut's with the short names of
:class:`~zcut.params.ZCutParams`: ``step_mm`` is ``step``), and convert to metres themselves.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
import types
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.errors import ConfigError
from replay.logs import layout
from replay.pipeline.methods import DEFAULT_METHODS, base_methods, parse_methods, registry, reported_methods
from zcut.cloud import Intrinsics
from zcut.errors import ParameterError
from zcut.params import (
    NOMINAL_MAX_DEPTH_MM,
    NOMINAL_RHO_THR,
    NOMINAL_STEP_MM,
    BinMaskParams,
    RegistrationParams,
    RemovalParams,
    SorParams,
    ZCutParams,
    a_max_from_camera,
)

if TYPE_CHECKING:
    from replay.logs.frame import Frame

#: How the z-cut's Δd and d_max are chosen: the paper's nominal values (its choice for all six
#: datasets, the default) or the §5.4 ranges applied to the part's geometry.
PARAMETER_MODES = ("nominal", "geometry")
#: Without a part size or a_max, assume a part's largest face covers this fraction of the image.
DEFAULT_FACE_FRACTION = 0.01

#: [zcut] keys of the file -> fields of ZCutParams; ``rho_thr`` is an input of the derivation only.
ZCUT_KEYS = {"step_mm": "step", "max_depth_mm": "max_depth", "max_area_px": "max_area", "a_max_px": "a_max",
             "connectivity": "connectivity"}
ZCUT_INPUTS = (*ZCUT_KEYS, "rho_thr")
#: The command-line options that set [zcut] keys (:func:`cli_layer`), for the notes.
_ZCUT_FLAGS = {"step_mm": "--step", "max_depth_mm": "--max-depth", "max_area_px": "--max-area", "rho_thr": "--rho"}
TOP_KEYS = ("part", "parameters", "preset", "methods")

#: The pipeline's own sections (the bin stages), before the methods' sections.
PIPELINE_SECTIONS: Mapping[str, type] = types.MappingProxyType(
    {"bin_mask": BinMaskParams, "registration": RegistrationParams, "removal": RemovalParams})
#: The methods' sections that are fields of :class:`PipelineConfig` (the others are its bank).
FIXED_METHOD_SECTIONS = ("zcut", "sor")


def stage_sections() -> dict[str, type]:
    """Every section but ``zcut`` -> its params class (the pipeline's, then the registry's methods')."""
    return {**PIPELINE_SECTIONS, **{m.section: m.params for m in registry().values() if m.section != "zcut"}}


def bank_sections() -> tuple[str, ...]:
    """The sections of the filter bank and the suspects: the registry's methods but the z-cut and SOR."""
    return tuple(m.section for m in registry().values() if m.section not in FIXED_METHOD_SECTIONS)


def section_names() -> tuple[str, ...]:
    """Every section, in the file's order: the pipeline's, then one per method of the registry."""
    return (*PIPELINE_SECTIONS, *(m.section for m in registry().values()))


def sections() -> dict[str, Any]:
    """Section name -> a function that validates the section's keys (raises ConfigError naming
    ``section.key`` and the value)."""
    return {name: _stage_section(name, cls) for name, cls in stage_sections().items()} | {"zcut": _zcut_section}


def _config_error(e: ParameterError, source: str | None = None) -> ConfigError:
    """A stage type's ParameterError in the file's words: ``ZCutParams.step`` -> ``zcut.step_mm``."""
    msg = str(e)
    head, _, rest = msg.partition(" ")
    cls, _, name = head.partition(".")
    class_section = {c.__name__: n for n, c in stage_sections().items()} | {"ZCutParams": "zcut"}
    if cls in class_section:
        if cls == "ZCutParams":
            name = {v: k for k, v in ZCUT_KEYS.items()}.get(name, name)
        msg = f"{class_section[cls]}.{name} {rest}"
    return ConfigError(f"{source}: {msg}" if source else msg)


def _zcut_section(**keys: Any) -> dict[str, Any]:
    """Validate a [zcut] table (each value as ZCutParams would; max_area_px, a_max_px optional)."""
    for k in keys:
        if k not in ZCUT_INPUTS:
            raise ConfigError(f"unknown key zcut.{k} (known: {', '.join(sorted(ZCUT_INPUTS))})")
    probe = {"step": 1.0, "max_depth": 1.0, "max_area": 1.0}
    for k, v in keys.items():
        if k == "rho_thr":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and 0 < v <= 1):
                raise ConfigError(f"zcut.rho_thr must be a number > 0 and <= 1, got {v!r}")
            continue
        if k in ("max_area_px", "a_max_px") and v is not None and not isinstance(v, bool) \
                and isinstance(v, (int, float)) and not math.isfinite(v):
            raise ConfigError(f"zcut.{k} must be a number > 0, got {v!r}")
        try:
            ZCutParams(**{**probe, ZCUT_KEYS[k]: v})
        except ParameterError as e:
            raise _config_error(e) from None
    return keys


def _stage_section(name: str, cls: type) -> Callable[..., Any]:
    def build(**keys: Any) -> Any:
        names = {f.name for f in dataclasses.fields(cls)}
        for k in keys:
            if k not in names:
                raise ConfigError(f"unknown key {name}.{k} (known: {', '.join(sorted(names))})")
        try:
            return cls(**keys)
        except ParameterError as e:
            raise _config_error(e) from None

    return build


class Bank(Mapping[str, Any]):
    """The filter bank's parameters of a config: section name -> params, in the registry's order
    (read-only and hashable, as the config's other fields)."""

    __slots__ = ("_items",)

    def __init__(self, items: Mapping[str, Any] | None = None) -> None:
        self._items = dict(items or {})

    def __getitem__(self, key: str) -> Any:
        return self._items[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __hash__(self) -> int:
        return hash(tuple(self._items.items()))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Mapping) and dict(self.items()) == dict(other.items())

    def __repr__(self) -> str:
        return f"Bank({self._items!r})"

    def __getstate__(self) -> dict[str, Any]:
        return self._items

    def __setstate__(self, state: dict[str, Any]) -> None:
        self._items = dict(state)


@dataclass(frozen=True, slots=True)
class PipelineConfig:
    """The whole pipeline's configuration (resolved: every value set).

    Attributes
    ----------
    zcut : ZCutParams
        Δd, d_max (mm), μ_thr (px), a_max (px, or None when unknown), connectivity.
    sor, bin_mask, registration, removal : the stage parameters of :mod:`zcut.params`
    bank : Bank
        The other methods' parameters (the filter bank's and the suspects', :func:`bank_sections`),
        by section, each read as an attribute (``config.radius``) and only when :attr:`methods`
        names its method; a section not given takes its class's defaults.
    part : str or None
        The part kind (``replay.presets.PART_KINDS`` key) whose geometry gave a_max (and Δd,
        d_max with ``parameters = "geometry"``).
    parameters : {"nominal", "geometry"}
        How Δd and d_max were chosen (before any explicit value in the file or on the command line).
    methods : tuple of str
        The filter methods every command runs, reports and scores (:mod:`replay.pipeline.methods`:
        base names and unions ``a+b``); default ``("zcut", "sor")``.
    """

    zcut: ZCutParams
    sor: SorParams = field(default_factory=SorParams)
    bin_mask: BinMaskParams = field(default_factory=BinMaskParams)
    registration: RegistrationParams = field(default_factory=RegistrationParams)
    removal: RemovalParams = field(default_factory=RemovalParams)
    bank: Mapping[str, Any] = field(default_factory=Bank)
    part: str | None = None
    parameters: str = "nominal"
    methods: tuple[str, ...] = DEFAULT_METHODS

    def __post_init__(self) -> None:
        own = stage_sections()
        for name in ("zcut", *PIPELINE_SECTIONS, "sor"):
            cls = ZCutParams if name == "zcut" else own[name]
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"PipelineConfig.{name} must be a {cls.__name__}, got {getattr(self, name)!r}")
        given = dict(self.bank)
        bank = {}
        for name in bank_sections():
            cls = own[name]
            bank[name] = given.pop(name) if name in given else cls()
            if not isinstance(bank[name], cls):
                raise ConfigError(f"PipelineConfig.{name} must be a {cls.__name__}, got {bank[name]!r}")
        if given:
            raise ConfigError(f"PipelineConfig.bank: unknown section {', '.join(given)} "
                              f"(known: {', '.join(bank_sections())})")
        object.__setattr__(self, "bank", Bank(bank))
        if self.parameters not in PARAMETER_MODES:
            raise ConfigError(f"parameters must be one of {', '.join(PARAMETER_MODES)}, got {self.parameters!r}")
        object.__setattr__(self, "methods", parse_methods(self.methods, source="PipelineConfig.methods"))

    @property
    def base_methods(self) -> tuple[str, ...]:
        """The base methods a replay runs for :attr:`methods` (the z-cut always)."""
        return base_methods(self.methods)

    @property
    def reported_methods(self) -> tuple[str, ...]:
        """The methods a report lists: :attr:`methods`, then ``union`` and ``intersection`` of zcut
        and sor when both are there."""
        return reported_methods(self.methods)

    def __getattr__(self, name: str) -> Any:
        """A bank section's parameters by its name (``config.radius``)."""
        if name.startswith("_") or name == "bank":
            raise AttributeError(name)
        try:
            return object.__getattribute__(self, "bank")[name]
        except (AttributeError, KeyError):
            raise AttributeError(f"'PipelineConfig' object has no attribute {name!r}") from None

    def replace(self, **changes: Any) -> PipelineConfig:
        """A copy with some stage parameters replaced, the bank's by their section name too
        (``config.replace(radius=...)``; e.g. one grid point of a sweep)."""
        bank = {k: changes.pop(k) for k in list(changes) if k in self.bank}
        if bank:
            changes["bank"] = {**changes.get("bank", self.bank), **bank}
        return dataclasses.replace(self, **changes)


def _config(zc: ZCutParams, stages: dict[str, Any], **rest: Any) -> PipelineConfig:
    """A config from its z-cut and every other section (``stage_sections()``'s names)."""
    fixed = {k: stages.pop(k) for k in (*PIPELINE_SECTIONS, "sor")}
    return PipelineConfig(zcut=zc, **fixed, bank=stages, **rest)


# ----------------------------------------------------------------------------------- dict layers


def to_dict(config: PipelineConfig) -> dict[str, Any]:
    """Nested dict of the config in the file's keys, ``None`` values left out (TOML has no null)."""
    out: dict[str, Any] = {"parameters": config.parameters}
    if config.part is not None:
        out["part"] = config.part
    out["methods"] = list(config.methods)
    for name in section_names():
        sec = getattr(config, name)
        if name == "zcut":
            out[name] = {k: getattr(sec, f) for k, f in ZCUT_KEYS.items() if getattr(sec, f) is not None}
        else:
            out[name] = {f.name: getattr(sec, f.name) for f in dataclasses.fields(sec)
                         if getattr(sec, f.name) is not None}
    return out


def config_sha256(config: PipelineConfig) -> str:
    """The identity of a resolved config: the sha256 of its values (:func:`to_dict`, keys sorted).

    Two configs have the same identity iff they run the same filter; a study's folder records it
    to refuse mixing runs of different configs.
    """
    import hashlib

    text = json.dumps(to_dict(config), sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def check_layer(layer: dict[str, Any], *, source: str) -> dict[str, Any]:
    """Validate one layer (keys and values); raise :class:`ConfigError` naming ``source``.

    ``preset = KIND`` is shorthand for ``part = KIND`` with ``parameters = "geometry"``.
    """
    if not isinstance(layer, dict):
        raise ConfigError(f"{source}: expected a table of sections, got {type(layer).__name__}")
    for key, value in layer.items():
        if key in ("part", "preset"):
            if value is not None and not isinstance(value, str):
                raise ConfigError(f"{source}: {key} must be a string, got {value!r}")
            if value is not None:
                _check_part(value, source=source, key=key)
            continue
        if key == "parameters":
            if value not in PARAMETER_MODES:
                raise ConfigError(f"{source}: parameters must be one of {', '.join(PARAMETER_MODES)}, got {value!r}")
            continue
        if key == "methods":
            parse_methods(value, source=f"{source}: methods")
            continue
        known = sections()
        if key not in known:
            raise ConfigError(f"{source}: unknown section [{key}] (known: {', '.join(section_names())}, "
                              f"{', '.join(TOP_KEYS)})")
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: [{key}] must be a table, got {value!r}")
        if key == "zcut" and "rho_thr" in value and "max_area_px" in value:
            raise ConfigError(f"{source}: give zcut.max_area_px or zcut.rho_thr, not both "
                              "(max_area_px = rho_thr × a_max_px)")
        try:
            known[key](**value)
        except ConfigError as e:
            raise ConfigError(f"{source}: {e}") from None
    return layer


def _check_part(kind: str, *, source: str, key: str = "part") -> None:
    from replay.presets import PART_KINDS

    if kind not in PART_KINDS:
        raise ConfigError(f"{source}: {key} must be one of {', '.join(PART_KINDS)}, got {kind!r}")


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML config file as a validated layer (nested dict).

    Raises :class:`ConfigError` naming the file for anything wrong in it: not UTF-8 text, not TOML,
    nested too deeply, unknown keys, bad values.
    """
    import os
    import stat

    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{p}: is a directory, not a config file")
    if p.exists() and not stat.S_ISREG(os.stat(p).st_mode):
        # /dev/zero, a FIFO, a terminal: never read without end
        raise ConfigError(f"{p}: not a regular file, not a config file")
    with open(p, "rb") as f:
        raw = f.read((1 << 20) + 1)
    if len(raw) > 1 << 20:
        raise ConfigError(f"{p}: too large for a config file (more than 1 MiB)")
    try:
        text = raw.decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a text file (not UTF-8): is it really the config?") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{p}: not valid TOML: {e}") from None
    except RecursionError:
        raise ConfigError(f"{p}: not valid TOML: nested too deeply") from None
    return check_layer(data, source=str(p))


def cli_layer(*, step: float | None = None, max_depth: float | None = None, max_area: float | None = None,
              rho: float | None = None, part: str | None = None, parameters: str | None = None,
              preset: str | None = None, methods: str | None = None) -> dict[str, Any]:
    """The command-line overrides (``--step/--max-depth/--max-area/--rho/--part/--parameters/
    --preset/--methods``) as a validated layer."""
    out: dict[str, Any] = {}
    if methods is not None:
        out["methods"] = list(parse_methods(methods, source="--methods"))
    for key, value in (("preset", preset), ("part", part), ("parameters", parameters)):
        if value is not None:
            out[key] = value
    z: dict[str, Any] = {}
    for key, number in (("step_mm", step), ("max_depth_mm", max_depth), ("max_area_px", max_area), ("rho_thr", rho)):
        if number is not None:
            z[key] = float(number)
    if z:
        out["zcut"] = z
    return check_layer(out, source="command line")


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
    """The config as TOML text that :func:`load_toml` reads back to the same config.

    ``max_area_px`` is written exactly (it decides which components are tagged); ρ_thr follows as
    a comment.
    """
    d = to_dict(config)
    lines = [f"# {line}" for line in header.splitlines()] if header else []
    lines.append(f"parameters = {_toml_value(d['parameters'])}")
    if "part" in d:
        lines.append(f"part = {_toml_value(d['part'])}")
    lines.append("methods = [" + ", ".join(_toml_value(m) for m in d["methods"]) + "]")
    for name in section_names():
        lines.append("")
        lines.append(f"[{name}]")
        for k, v in d[name].items():
            line = f"{k} = {_toml_value(v)}"
            if name == "zcut" and k == "max_area_px" and config.zcut.rho_thr is not None:
                line += f"  # rho_thr = {config.zcut.rho_thr:.6g} of a_max_px"
            lines.append(line)
    return "\n".join(lines).lstrip("\n") + "\n"


def from_dict(d: dict[str, Any], *, source: str = "config") -> PipelineConfig:
    """A resolved config from a nested dict in the file's keys (``zcut.max_area_px`` must be set,
    e.g. a config written by :func:`to_toml`); missing sections take the defaults."""
    check_layer(d, source=source)
    z = dict(d.get("zcut", {}))
    if z.get("max_area_px") is None:
        raise ConfigError(f"{source}: zcut.max_area_px is not set (a resolved config has it)")
    z.pop("rho_thr", None)
    z.setdefault("step_mm", NOMINAL_STEP_MM)
    z.setdefault("max_depth_mm", NOMINAL_MAX_DEPTH_MM)
    try:
        zc = ZCutParams(**{ZCUT_KEYS[k]: v for k, v in z.items()})
        stages = {name: cls(**d.get(name, {})) for name, cls in stage_sections().items()}
    except ParameterError as e:
        raise _config_error(e, source) from None
    part = d.get("part") if d.get("part") is not None else d.get("preset")
    mode = d.get("parameters") or ("geometry" if d.get("preset") else "nominal")
    return _config(zc, stages, part=part, parameters=mode, methods=tuple(d.get("methods", DEFAULT_METHODS)))


# ----------------------------------------------------------------------------------- resolution


@dataclass(frozen=True, slots=True)
class Resolved:
    """A resolved config and what the resolution decided, for the user to read."""

    config: PipelineConfig
    notes: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class LogFacts:
    """What a log tells about its parameters (gathered by :func:`log_facts`).

    Attributes
    ----------
    part : str or None
        Part kind from a synthetic log's ``zcut.synth`` metadata.
    camera_distance_mm : float or None
        The distance a part's face is seen from: the synthetic log's, else the first frame's
        median depth.
    intrinsics : Intrinsics or None
        From the log's CameraInfo, else fitted to the first frame's organized cloud.
    image_shape : (H, W)
    sources : dict[str, str]
        Where each fact came from, for the notes.
    intrinsics_fitted : bool
        ``intrinsics`` were fitted to the cloud: the log has no camera model (no CameraInfo), which
        the methods that need one (``cluster``) refuse.
    recorded_masks : tuple of (str, str)
        ``(method, topic)`` of every mask a stereo log's ``zcut.stereo`` metadata lists as recorded (the
        matcher's post-filters, ``zcut record-stereo``); empty for any other log.
    """

    part: str | None
    camera_distance_mm: float | None
    intrinsics: Intrinsics | None
    image_shape: tuple[int, int]
    sources: dict[str, str] = field(default_factory=dict)
    intrinsics_fitted: bool = False
    recorded_masks: tuple[tuple[str, str], ...] = ()


def synth_info(metadata: dict[str, dict[str, str]]) -> tuple[str | None, float | None]:
    """(part kind, camera distance in mm) from a log's ``zcut.synth`` metadata (None when absent)."""
    meta = metadata.get(layout.SYNTH_METADATA, {})
    kind = meta.get("part_kind") or None
    if kind == "empty":  # an empty-bin log has no parts to derive parameters from
        kind = None
    dist = None
    for key, scale in (("a_max_distance_mm", 1.0), ("pile_distance_mm", 1.0), ("camera_distance_mm", 1.0),
                       ("pile_distance_m", 1000.0), ("camera_distance_m", 1000.0)):
        if key in meta:
            try:
                d = float(meta[key]) * scale
            except ValueError:
                continue
            if math.isfinite(d) and d > 0:
                dist = d
                break
    return kind, dist


def recorded_masks(metadata: dict[str, dict[str, str]]) -> tuple[tuple[str, str], ...]:
    """``(method, topic)`` of each post-filter mask a ``zcut record-stereo`` log records (its ``zcut.stereo``
    metadata's ``rejected``), in the recorded order; empty when there is none. Entries that are not a
    ``{"method": str, "topic": str}`` are left out (the method then does not join a default)."""
    text = metadata.get(layout.STEREO_METADATA, {}).get("rejected")
    if not text:
        return ()
    try:
        items = json.loads(text)
    except ValueError:
        return ()
    if not isinstance(items, list):
        return ()
    return tuple((e["method"], e["topic"]) for e in items
                 if isinstance(e, dict) and isinstance(e.get("method"), str) and isinstance(e.get("topic"), str))


def intrinsics_from_cloud(xyz: np.ndarray) -> Intrinsics | None:
    """Pinhole intrinsics fitted to an organized cloud (x/z = (u - cx)/fx, y/z = (v - cy)/fy).

    Least squares over the valid points with z > 0; None when fewer than 100 such points or a
    non-positive focal length comes out.
    """
    h, w = xyz.shape[:2]
    z = xyz[..., 2].astype(np.float64)
    ok = np.isfinite(xyz).all(axis=2) & (z > 0)
    if ok.sum() < 100:
        return None
    v, u = np.nonzero(ok)
    fits = []
    for coord, pix in ((xyz[..., 0][ok] / z[ok], u), (xyz[..., 1][ok] / z[ok], v)):
        slope, intercept = np.polyfit(pix.astype(np.float64), coord.astype(np.float64), 1)
        if not (slope > 0 and math.isfinite(1.0 / slope)):
            return None
        fits.append((1.0 / slope, -intercept / slope))
    (fx, cx), (fy, cy) = fits
    try:
        return Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h)
    except ParameterError:
        return None


def log_facts(metadata: dict[str, dict[str, str]], first_frame: Frame, *,
              intrinsics: Intrinsics | None = None) -> LogFacts:
    """The facts :func:`resolve` needs, from a log's metadata and its first readable frame.

    Parameters
    ----------
    metadata : dict
        The log's MCAP metadata records.
    first_frame : replay.logs.frame.Frame
        The log's first readable frame (whatever frame range a command processes).
    intrinsics : Intrinsics, optional
        The log's camera intrinsics (its first readable CameraInfo); else the frame's, else
        fitted to the frame's cloud.
    """
    sources: dict[str, str] = {}
    part, distance = synth_info(metadata)
    if part is not None:
        sources["part"] = "the log's zcut.synth metadata"
    if distance is not None:
        sources["camera_distance_mm"] = "the log's zcut.synth metadata"
    else:
        z = first_frame.xyz[..., 2]
        z = z[np.isfinite(z)]
        if z.size:
            distance = float(np.median(z)) * 1000.0
            sources["camera_distance_mm"] = f"the median depth of the first frame, {distance:.0f} mm"
    K = intrinsics if intrinsics is not None else first_frame.intrinsics
    fitted = K is None
    if K is not None:
        sources["intrinsics"] = "the log's CameraInfo"
    else:
        K = intrinsics_from_cloud(first_frame.xyz)
        if K is not None:
            sources["intrinsics"] = f"fitted to the first frame's organized cloud: fx {K.fx:.1f}, fy {K.fy:.1f} px"
    return LogFacts(part, distance if (distance is None or distance > 0) else None, K, first_frame.shape, sources,
                    intrinsics_fitted=fitted, recorded_masks=recorded_masks(metadata))


def _merge(*layers: dict[str, Any]) -> tuple[dict[str, Any], str | None]:
    """Deep-merge validated layers; also say which of max_area_px / rho_thr was given last."""
    out: dict[str, Any] = {}
    area_key = None
    for layer in layers:
        for key, value in layer.items():
            if key == "preset":
                if value is not None:
                    out["part"], out["parameters"] = value, "geometry"
                continue
            if key in ("part", "parameters", "methods"):
                out[key] = value
                continue
            out.setdefault(key, {}).update(value)
            if key == "zcut":
                for k in ("max_area_px", "rho_thr"):
                    if k in value:
                        area_key = k
    return out, area_key


def resolve(facts: LogFacts, *, file_layer: dict[str, Any] | None = None,
            cli: dict[str, Any] | None = None) -> Resolved:
    """The one function that fills in derived values: the resolved config and its notes.

    Parameters
    ----------
    facts : LogFacts
        From :func:`log_facts`.
    file_layer : dict, optional
        From :func:`load_toml`.
    cli : dict, optional
        From :func:`cli_layer`.

    Returns
    -------
    Resolved
    """
    from replay.presets import BIN, PART_KINDS

    d, area_key = _merge(file_layer or {}, cli or {})
    notes: list[str] = []
    part = d.get("part")
    if part is not None:
        notes.append(f"part: {part} (from {'the command line' if (cli or {}).get('part') or (cli or {}).get('preset') else 'the config file'})")
    elif facts.part is not None:
        part = facts.part
        notes.append(f"part: {part} (from {facts.sources.get('part', 'the log')})")
    mode = d.get("parameters", "nominal")
    z = dict(d.get("zcut", {}))

    def given(key: str) -> str | None:
        """Where a [zcut] key the layers set came from (the last layer wins), None if none set it."""
        if key in (cli or {}).get("zcut", {}):
            return f"{_ZCUT_FLAGS[key]}, the command line" if key in _ZCUT_FLAGS else "the command line"
        if key in (file_layer or {}).get("zcut", {}):
            return f"zcut.{key}, the config file"
        return None

    if mode == "geometry":
        if part is None:
            raise ConfigError("parameters = \"geometry\" needs the part kind: give part = KIND (or --part KIND)")
        kind = PART_KINDS[part]
        g = ZCutParams.from_geometry(p_min_mm=kind.p_min_mm, bin_height_mm=BIN.height_mm, a_max_px=1.0)
        step, depth = g.step, g.max_depth
        derived = (f"the paper's §5.4 ranges for {part} (p_min {kind.p_min_mm:g} mm, bin height {BIN.height_mm:g} mm): "
                   "Δd = 0.02·p_min, d_max = 3·p_min in [p_min, 0.7·b_h]")
        step_src, depth_src = f"0.02·p_min of {part}, paper §5.4", f"3·p_min of {part}, paper §5.4"
    else:
        step, depth = NOMINAL_STEP_MM, NOMINAL_MAX_DEPTH_MM
        derived = f"the paper's nominal values ({NOMINAL_STEP_MM:g} mm, {NOMINAL_MAX_DEPTH_MM:g} mm)"
        step_src = depth_src = "the paper's nominal value"
    step = z.get("step_mm", step)
    depth = z.get("max_depth_mm", depth)
    if given("step_mm") is None and given("max_depth_mm") is None:
        notes.append(f"z-cut Δd and d_max from {derived}" if mode == "geometry" else f"z-cut Δd and d_max: {derived}")
    else:  # say where each value came from: a value given overrides the derivation
        notes.append(f"z-cut Δd = {step:g} mm ({given('step_mm') or step_src}), "
                     f"d_max = {depth:g} mm ({given('max_depth_mm') or depth_src})")
    a_max = z.get("a_max_px")
    if a_max is not None:
        notes.append(f"a_max = {a_max:g} px (given: {given('a_max_px')})")
    elif part is not None and facts.intrinsics is not None and facts.camera_distance_mm is not None:
        K = facts.intrinsics
        a_max = a_max_from_camera(PART_KINDS[part].face_area_mm2, distance_mm=facts.camera_distance_mm,
                                  fx_px=K.fx, fy_px=K.fy)
        notes.append(f"a_max = {a_max:.1f} px: the {part} part's largest face ({PART_KINDS[part].face_area_mm2:.0f} mm²) "
                     f"at {facts.camera_distance_mm:.0f} mm (distance: {facts.sources.get('camera_distance_mm', '?')}; "
                     f"intrinsics: {facts.sources.get('intrinsics', '?')})")
    elif area_key != "max_area_px":
        h, w = facts.image_shape
        a_max = DEFAULT_FACE_FRACTION * h * w
        why = "no part known" if part is None else "the camera is not known"
        notes.append(f"{why}: a_max = {DEFAULT_FACE_FRACTION:.0%} of the image = {a_max:.0f} px "
                     f"(set zcut.a_max_px, part = KIND or --max-area)")
    if area_key == "max_area_px":
        max_area = z["max_area_px"]
        notes.append(f"μ_thr = {max_area:g} px (given: {given('max_area_px')})")
    else:
        rho = z.get("rho_thr", NOMINAL_RHO_THR)
        max_area = rho * a_max
        rho_src = given("rho_thr") or "the paper's nominal value"
        notes.append(f"μ_thr = ρ_thr · a_max = {rho:g} × {a_max:.1f} = {max_area:.2f} px (ρ_thr: {rho_src})")
    try:
        zc = ZCutParams(step=step, max_depth=depth, max_area=max_area, a_max=a_max,
                        connectivity=z.get("connectivity", 8))
        stages = {name: cls(**d.get(name, {})) for name, cls in stage_sections().items()}
    except ParameterError as e:
        raise _config_error(e, "resolved config") from None
    config = _config(zc, stages, part=part, parameters=mode, methods=tuple(d.get("methods", DEFAULT_METHODS)))
    sensor = () if "methods" in d else sensor_methods(config, facts)
    if sensor:
        config = dataclasses.replace(config, methods=(*config.methods, *sensor))
        notes.append(f"methods: {', '.join(config.methods)} ({', '.join(sensor)}: the stereo matcher's post-filter "
                     "masks the log records, at the config's strengths; methods = [...] or --methods to choose)")
    check_camera_model(config, facts)
    if config.methods != DEFAULT_METHODS and not sensor:
        notes.append(f"methods: {', '.join(config.methods)}")
    notes.append(f"z-cut: step {zc.step:g} mm, max depth {zc.max_depth:g} mm, max area {zc.max_area:.2f} px; "
                 f"SOR: k {config.sor.k}, std_ratio {config.sor.std_ratio:g} on the "
                 f"{'top of the pile (within d_max of the highest point)' if config.sor.region == 'top' else 'whole zone'}")
    return Resolved(config, tuple(notes))


def sensor_methods(config: PipelineConfig, facts: LogFacts) -> tuple[str, ...]:
    """The post-filter methods a log's default methods add (docs/labelling_real.md, h/stereo4): each of
    ``zcut.stereo.POST_FILTERS``, in its order, whose mask the log records (:attr:`LogFacts.recorded_masks`)
    at the strength ``config`` selects for it (its section); none for a log without recorded masks."""
    if not facts.recorded_masks:
        return ()
    from zcut.stereo import POST_FILTERS

    held = set(facts.recorded_masks)
    return tuple(name for name in POST_FILTERS
                 if (name, layout.stereo_rejected_topic(dataclasses.asdict(config.bank[name]))) in held)


def check_camera_model(config: PipelineConfig, facts: LogFacts) -> None:
    """Refuse methods that need the camera model (``cluster``: areas in mm²) on a log without one.

    Raises
    ------
    ConfigError
        One line naming the methods and what to do.
    """
    if facts.intrinsics is not None and not facts.intrinsics_fitted:
        return
    need = [m.name for m in registry().values() if m.needs_intrinsics and m.name in config.base_methods]
    if need:
        raise ConfigError(f"{', '.join(need)} needs the camera model (fx, fy) and the log has none (no CameraInfo): "
                          f"leave {', '.join(need)} out of methods, or record the log with its camera info "
                          "(zcut record --camera-info FILE.yaml, or --fx --fy --cx --cy)")
