"""The filter methods a replay runs and scores: one registry, so that every command knows the same names.

A *method* is a named outlier filter that judges the zone of a frame (the pixels the bin stages left,
:class:`replay.pipeline.zone.Zone`) and returns its outliers there. ``zcut`` (the paper's filter)
and ``sor`` (its comparison) are methods; so is every filter added to the bank. A method reads its
parameters from its own section of the resolved :class:`~replay.pipeline.config.PipelineConfig`
(``config.zcut``, ``config.sor``, ...), never from loose keywords.

The config's ``methods`` list (``--methods`` on the command line) names the methods a command runs,
reports and scores, and unions of them written ``a+b`` (e.g. ``zcut+mixed_pixel``): a union is
derived from the masks of its members, never run on its own. ``union`` and ``intersection`` are the
report's two derived methods of ``zcut`` and ``sor`` (docs/accuracy.md), present whenever both are.

Adding a filter is one :class:`Method` entry in :data:`BUILTIN` (its module in ``zcut/`` and its
parameters class in ``zcut/params.py`` beside it): the entry declares its name, parameters class (the
config section of that name, whose keys are the class's fields), summary, run function, whether it
needs the camera model, its default sweep axes (``--grid NAME=default``) and its warm-up. The
config's sections and bank (:mod:`replay.pipeline.config`), the sweep's default axes
(:mod:`studies.bank`) and the install's warm-up (:mod:`replay.warmup`) are views of the registry. A
method kept outside the tree (or a test's toy method) is plugged in by naming it in the environment
variable ``ZCUT_METHODS`` (:data:`PLUGINS_ENV`), which reaches every command and its worker processes.

Which points each method sees (docs/filters.md, "In the pipeline"): every method judges the zone and
returns outliers in the zone only (the pipeline adds the points above the rim to every method alike).
The point-set filters, ``sor`` and ``radius``, see the zone's points only, as a library's filter sees
the cloud the bin stages cropped (SOR, by default, only the top of the pile: ``sor.region``). The
grid filters, ``cluster``, ``speckle``, ``window`` and ``mixed_pixel``, are the camera's own filters:
they see every valid point of the frame, as the camera's firmware does before any bin removal, so
that a part's pixels next to the removed bin floor keep their neighbours; only their verdicts inside
the zone count. ``suspects`` sees every valid point as context and judges the zone (its own
contract, docs/filters.md "Suspects").
"""

from __future__ import annotations

import importlib
import os
import types
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.errors import ConfigError
from zcut.params import (
    ClusterParams,
    ExplainedParams,
    MixedPixelParams,
    RadiusParams,
    SorParams,
    SpeckleParams,
    StereoLrParams,
    StereoSpeckleParams,
    StereoTextureParams,
    StereoUniquenessParams,
    SuspectParams,
    WindowParams,
    ZCutParams,
    ZCutTopParams,
)

if TYPE_CHECKING:  # the registry is read by every command's parser: it loads no numba, OpenCV nor Open3D
    from replay.logs.frame import Frame
    from replay.pipeline.zone import Zone

#: The methods a config runs when it names none: the paper's filter and its comparison.
DEFAULT_METHODS: tuple[str, ...] = ("zcut", "sor")
#: The report's derived methods of ``zcut`` and ``sor`` (present whenever both are).
DERIVED: tuple[str, ...] = ("union", "intersection")
#: Joins the members of a union (``zcut+mixed_pixel``).
UNION_SEP = "+"
#: The environment variable that plugs in methods kept outside the tree: comma-separated
#: ``module:NAME`` items, each ``NAME`` a :class:`Method` or a tuple of them (``module`` importable).
PLUGINS_ENV = "ZCUT_METHODS"


@dataclass(frozen=True, slots=True)
class MethodOutput:
    """What one method found on one frame.

    Attributes
    ----------
    outliers : (H, W) bool ndarray
        The method's outliers inside the zone (the easy outliers above the rim are added by the
        pipeline, for every method alike).
    detail : object or None
        The method's own result for the viewer and the page (the z-cut's ``CutResult``), or None.
    warning : str or None
        Why the method could not judge this frame (it then returns no outliers), for the user.
    """

    outliers: np.ndarray
    detail: Any = None
    warning: str | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class Method:
    """One filter of the registry: everything the commands need to know of it, declared once.

    Attributes
    ----------
    name : str
        The name in ``methods`` lists, reports, tables and Rerun entity paths.
    params : type
        Its parameters class (a frozen dataclass of :mod:`zcut.params` whose every field has a
        default and which raises :class:`zcut.errors.ParameterError` naming ``Class.field`` on a bad
        value): the config section's keys are its fields.
    summary : str
        One line for ``--help`` and the docs.
    run : callable
        ``run(frame, zone, config) -> MethodOutput``: the frame (``replay.logs.frame.Frame``), its
        zone (``replay.pipeline.zone.Zone``) and the resolved config, whose ``config.<section>``
        holds the method's parameters.
    needs_intrinsics : bool
        It needs the camera model (a log without one gets a named warning and no outliers).
    axes : mapping of str to tuple
        Its default sweep axes (``--grid NAME=default``): a few values of some fields, from a light
        to a strong filter; empty when it has none (then the sweep runs it at the config's values).
    warmup : callable or None
        ``warmup()`` runs its numba kernels once on tiny inputs (``python -m replay.warmup``); None
        when it compiles nothing.
    section : str
        The config section holding its parameters (default: its name).
    """

    name: str
    params: type
    summary: str
    run: Callable[..., MethodOutput]
    needs_intrinsics: bool = False
    axes: Mapping[str, tuple[Any, ...]] = field(default_factory=dict, compare=False)
    warmup: Callable[[], None] | None = field(default=None, compare=False)
    section: str = ""

    def __post_init__(self) -> None:
        if not self.section:
            object.__setattr__(self, "section", self.name)
        object.__setattr__(self, "axes", types.MappingProxyType({k: tuple(v) for k, v in self.axes.items()}))


#: The resolved :class:`~replay.pipeline.config.PipelineConfig` a method runs with (not imported: the config
#: imports this module), read by section name, ``config.<section>`` (the bank's sections are views of the registry).
Config = Any


def _run_zcut(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    cut = zone.cut(config.zcut)  # find_clusters on the zone's heights, shared with SOR's top region
    return MethodOutput(cut.outliers & zone.zone, cut)


def _run_zcut_top(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from zcut.cut_top import find_clusters_top

    a_max = config.zcut.a_max
    if a_max is None:
        return MethodOutput(np.zeros_like(zone.zone), warning="zcut_top needs the part's largest face: set "
                            "zcut.a_max_px (or part = KIND) instead of zcut.max_area_px alone")
    cut = find_clusters_top(zone.height_mm, params=config.zcut, top_area=config.zcut_top.top_faces * a_max)
    return MethodOutput(cut.outliers & zone.zone, cut)


def _run_sor(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from replay.pipeline.zone import sor_on_zone

    if not config.sor.enabled:
        return MethodOutput(np.zeros_like(zone.zone), warning="SOR disabled (sor.enabled = false)")
    return MethodOutput(sor_on_zone(frame, zone, config))


def _in_zone(zone: Zone, mask: np.ndarray) -> MethodOutput:
    return MethodOutput(mask & zone.zone)


def _run_radius(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from replay.pipeline.zone import zone_crop
    from zcut.radius import radius_stage

    out = np.zeros_like(zone.zone)
    crop = zone_crop(frame.xyz, zone.zone, whole=zone.removal is None)
    if crop is not None:
        sl, sub = crop
        out[sl] = radius_stage(sub, params=config.radius) & zone.zone[sl]
    return MethodOutput(out)


def _run_cluster(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from zcut.components import cluster_stage

    return _in_zone(zone, cluster_stage(frame.xyz, params=config.cluster, intrinsics=frame.intrinsics))


def _run_speckle(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from zcut.components import speckle_stage

    return _in_zone(zone, speckle_stage(frame.xyz, params=config.speckle))


def _run_window(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from zcut.local_rules import window_stage

    return _in_zone(zone, window_stage(frame.xyz, params=config.window))


def _run_mixed_pixel(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from zcut.local_rules import mixed_pixel_stage

    return _in_zone(zone, mixed_pixel_stage(frame.xyz, params=config.mixed_pixel))


def suspect_params(config: Config) -> Any:
    """The config's :class:`~zcut.params.SuspectParams`, with the z-cut's a_max when its own is not set."""
    import dataclasses

    p = config.suspects
    if p.a_max is None and config.zcut.a_max is not None:
        p = dataclasses.replace(p, a_max=config.zcut.a_max)
    return p


def _run_suspects(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from zcut.suspects import suspects

    K = frame.intrinsics
    if K is not None and (K.height, K.width) != tuple(zone.zone.shape):
        K = None  # the size check is the frame reader's; the detectors need nothing else from the camera
    res = suspects(frame.xyz, zone.height_mm, zone.zone, zone.easy, params=suspect_params(config), intrinsics=K)
    return MethodOutput(res.mask & zone.zone, res)


def _run_stereo(frame: Frame, zone: Zone, name: str, params: Any) -> MethodOutput:
    from replay.pipeline.stereo_methods import rejected

    mask, warning = rejected(frame, zone, name, params)
    return MethodOutput(mask, warning=warning)


def _run_stereo_uniqueness(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    return _run_stereo(frame, zone, "stereo_uniqueness", config.stereo_uniqueness)


def _run_stereo_lr(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    return _run_stereo(frame, zone, "stereo_lr", config.stereo_lr)


def _run_stereo_speckle(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    return _run_stereo(frame, zone, "stereo_speckle", config.stereo_speckle)


def _run_stereo_texture(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    return _run_stereo(frame, zone, "stereo_texture", config.stereo_texture)


def _run_explained(frame: Frame, zone: Zone, config: Config) -> MethodOutput:
    from replay.pipeline.explained import run_explained

    mask, detail, warning = run_explained(frame, zone, config)
    return MethodOutput(mask, detail, warning)


# ------------------------------------------------------------------------------------- warm-ups
def _tiny() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tiny inputs for the warm-ups: a height image, its organized cloud (mm-sized, float32) and a
    scattered cloud (no camera: SOR's column search)."""
    rng = np.random.default_rng(0)
    h = rng.normal(size=(40, 50)).cumsum(axis=0)
    xyz = np.dstack([*np.meshgrid(np.arange(50.0), np.arange(40.0)), 500 + h]).astype(np.float32)
    scattered = rng.normal(size=(40, 50, 3)).astype(np.float32)
    return h, xyz, scattered


def _bank_clouds() -> Iterable[np.ndarray]:
    """The filter bank's warm-up clouds: float32 and float64, organized and scattered."""
    _, xyz, scattered = _tiny()
    for cloud in (xyz / 1000.0, scattered):
        for dtype in (np.float32, np.float64):
            yield cloud.astype(dtype)


def _camera() -> Any:
    from zcut.cloud import Intrinsics

    return Intrinsics(fx=300.0, fy=300.0, cx=25.0, cy=20.0, width=50, height=40)


def _warm_zcut() -> None:
    from zcut.cut_grid import zcut_tree
    from zcut.cuts import find_clusters, zcut_outliers

    h, _, _ = _tiny()
    zcut_outliers(h, step=0.2, max_depth=3.0, max_area=20)
    for kernel in ("flood", "union-find"):
        find_clusters(h, params=ZCutParams(step=0.2, max_depth=3.0, max_area=20.0), kernel=kernel)
    tree = zcut_tree(h, step=0.2, max_depth=3.0)
    tree.counts([1.0, 3.0], [5.0, 20.0], truth=h > 1, scored=np.ones(h.shape, bool))


def _warm_zcut_top() -> None:
    from zcut.cut_top import find_clusters_top

    h, _, _ = _tiny()
    find_clusters_top(h, params=ZCutParams(step=0.2, max_depth=3.0, max_area=20.0), top_area=50.0)


def _warm_sor() -> None:
    from zcut.sor import sor_outliers

    _, xyz, scattered = _tiny()
    for convention in ("pcl", "open3d"):
        sor_outliers(xyz, k=4, convention=convention)
        sor_outliers(xyz.astype(np.float64) * [1, 1, -1], k=4, convention=convention)
        sor_outliers(scattered, k=4, convention=convention)


def _warm_radius() -> None:
    from zcut.radius import radius_outliers

    for a in _bank_clouds():
        radius_outliers(a, 2.0, 8)


def _warm_cluster() -> None:
    from zcut.components import cluster_outliers

    for a in _bank_clouds():
        cluster_outliers(a, max_neighbour_mm=3.0, min_area_mm2=50.0, intrinsics=_camera())


def _warm_speckle() -> None:
    from zcut.components import speckle_outliers

    for a in _bank_clouds():
        speckle_outliers(a, max_diff_mm=2.0, max_size_px=100)


def _warm_window() -> None:
    from zcut.local_rules import window_outliers

    for a in _bank_clouds():
        window_outliers(a, min_inliers=3, rel_tolerance=0.005)


def _warm_mixed_pixel() -> None:
    from zcut.local_rules import mixed_pixel_outliers

    for a in _bank_clouds():
        mixed_pixel_outliers(a, min_angle_deg=8.0)


def _warm_suspects() -> None:
    from zcut.suspects import suspects

    h, xyz, _ = _tiny()
    suspects(xyz / 1000.0, -np.asarray(xyz[..., 2], np.float64), np.ones(h.shape, bool), params=SuspectParams())


# ------------------------------------------------------------------------------------ the registry
#: Every method of the tree, in the registry's order (the order of reports, tables and config
#: sections). Adding a filter is one entry here.
BUILTIN: tuple[Method, ...] = (
    Method(name="zcut", params=ZCutParams, run=_run_zcut, warmup=_warm_zcut,
           summary="the paper's z-cut: floating clusters smaller than μ_thr, found by descending cuts"),
    Method(name="sor", params=SorParams, run=_run_sor, warmup=_warm_sor,
           summary="statistical outlier removal, the paper's comparison (PCL / MATLAB pcdenoise)"),
    Method(name="radius", params=RadiusParams, run=_run_radius, warmup=_warm_radius,
           axes={"radius_mm": (1.0, 2.0, 4.0), "min_points": (2, 4, 8, 16)},
           summary="radius outlier removal: too few other points within a ball (Open3D, PCL)"),
    Method(name="cluster", params=ClusterParams, run=_run_cluster, warmup=_warm_cluster, needs_intrinsics=True,
           axes={"max_neighbour_mm": (1.0, 3.0, 6.0), "min_area_mm2": (10.0, 50.0, 200.0)},
           summary="cluster removal: small 3D-connected groups of pixels, by area in mm² (Zivid)"),
    Method(name="speckle", params=SpeckleParams, run=_run_speckle, warmup=_warm_speckle,
           axes={"max_diff_mm": (0.5, 2.0, 5.0), "max_size_px": (25, 100, 400)},
           summary="speckle removal: small regions cut off by depth jumps (OpenCV, Ensenso)"),
    Method(name="window", params=WindowParams, run=_run_window, warmup=_warm_window,
           axes={"min_inliers": (1, 3, 5), "rel_tolerance": (0.001, 0.005, 0.02)},
           summary="3 × 3 window rule: too few neighbours within a relative depth tolerance (Basler)"),
    Method(name="mixed_pixel", params=MixedPixelParams, run=_run_mixed_pixel, warmup=_warm_mixed_pixel,
           axes={"min_angle_deg": (2.0, 5.0, 8.0, 12.0, 20.0)},
           summary="mixed pixels: the surface leaves the pixel along its ray (ifm)"),
    Method(name="suspects", params=SuspectParams, run=_run_suspects, warmup=_warm_suspects,
           summary="the labelling page's suspects: every detector of zcut.suspects, united (not a filter to ship)"),
    # the stereo matcher's own post-filters, read from a `zcut record-stereo` log (replay/pipeline/stereo_methods.py)
    Method(name="stereo_uniqueness", params=StereoUniquenessParams, run=_run_stereo_uniqueness,
           axes={"uniqueness_ratio": (5, 10, 15, 25)},
           summary="stereo logs: the pixels the matcher's uniqueness test rejects (recorded by record-stereo)"),
    Method(name="stereo_lr", params=StereoLrParams, run=_run_stereo_lr, axes={"disp12_max_diff": (0, 1, 2, 4)},
           summary="stereo logs: the pixels the matcher's left-right check rejects (recorded by record-stereo)"),
    Method(name="stereo_speckle", params=StereoSpeckleParams, run=_run_stereo_speckle,
           axes={"speckle_window": (50, 100, 200, 400), "speckle_range": (1, 2, 4)},
           summary="stereo logs: the pixels the matcher's speckle filter rejects (recorded by record-stereo)"),
    Method(name="stereo_texture", params=StereoTextureParams, run=_run_stereo_texture,
           axes={"texture_threshold": (10, 200, 800, 1600)},
           summary="stereo logs (bm): the pixels StereoBM's texture test rejects (recorded by record-stereo)"),
    Method(name="explained", params=ExplainedParams, run=_run_explained,
           axes={"k": (2.0, 3.0, 5.0)},
           summary="the paper's §2: farther than k × Err from every known surface (part fits, bin, table)"),
    Method(name="zcut_top", params=ZCutTopParams, run=_run_zcut_top, warmup=_warm_zcut_top,
           axes={"top_faces": (0.25, 1.0, 4.0)},
           summary="the z-cut (section zcut) with d_max measured from the pile's top, not from the highest point"),
)
_BUILTIN_MAP = types.MappingProxyType({m.name: m for m in BUILTIN})


def plugins(spec: str) -> tuple[Method, ...]:
    """The methods a :data:`PLUGINS_ENV` value names (``"pkg.mod:TOY,pkg.other:METHODS"``).

    Raises
    ------
    ConfigError
        One line: an item not ``module:NAME``, a module that does not import, a name that is not a
        Method (or a tuple of them).
    """
    out: list[Method] = []
    for item in (i.strip() for i in spec.split(",")):
        if not item:
            continue
        module, colon, attr = item.partition(":")
        if not colon or not module or not attr:
            raise ConfigError(f"{PLUGINS_ENV}: expected module:NAME items, got {item!r}")
        try:
            found = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as e:
            raise ConfigError(f"{PLUGINS_ENV}: cannot load {item!r}: {e}") from None
        entries = found if isinstance(found, (tuple, list)) else (found,)
        for m in entries:
            if not isinstance(m, Method):
                raise ConfigError(f"{PLUGINS_ENV}: {item!r} is not a Method (or a tuple of them): {m!r}")
            out.append(m)
    return tuple(out)


def registry() -> Mapping[str, Method]:
    """Every method zcut knows, by name (a read-only mapping): :data:`BUILTIN`, then the plug-ins
    :data:`PLUGINS_ENV` names (read on each call, so that a test's toy method reaches every command).

    A plug-in that does not load is left out here (the parser's help lists the methods before any
    error can be reported as one line); :func:`parse_methods`, which every config runs, refuses it.
    """
    try:
        return _registry()
    except ConfigError:
        return _BUILTIN_MAP


def _registry() -> Mapping[str, Method]:
    """:func:`registry`, raising :class:`ConfigError` for a plug-in that does not load or whose name
    or section is already taken."""
    spec = os.environ.get(PLUGINS_ENV, "")
    if not spec.strip():
        return _BUILTIN_MAP
    out = dict(_BUILTIN_MAP)
    sections = {m.section for m in BUILTIN} | {"bin_mask", "registration", "removal"}
    for m in plugins(spec):
        if m.name in out or m.section in sections or UNION_SEP in m.name or m.name in DERIVED:
            raise ConfigError(f"{PLUGINS_ENV}: method {m.name!r} (section {m.section!r}) is already taken or not "
                              f"a valid name")
        out[m.name] = m
        sections.add(m.section)
    return types.MappingProxyType(out)


def members(name: str) -> tuple[str, ...]:
    """The base methods a method name stands for: ``"a+b"`` -> ``("a", "b")``, ``"union"`` ->
    ``("zcut", "sor")``, a base name -> itself."""
    if name in DERIVED:
        return DEFAULT_METHODS
    return tuple(name.split(UNION_SEP))


def parse_methods(value: str | Iterable[str], *, source: str = "methods") -> tuple[str, ...]:
    """Validate a methods list (``"zcut,sor,radius"`` or a list of names) against the registry.

    Returns the names in the given order, duplicates removed. A union ``a+b`` is written with its
    members in the given order; ``union`` and ``intersection`` are accepted as the derived methods of
    zcut and sor.

    Raises
    ------
    ConfigError
        An empty list, an unknown name (naming the known ones), an empty member (``zcut+``); a
        plug-in of :data:`PLUGINS_ENV` that does not load.
    """
    if isinstance(value, str):
        items = [v.strip() for v in value.split(",")]
    elif isinstance(value, (list, tuple)):
        items = list(value)
    else:
        raise ConfigError(f"{source} must be a list of method names, got {value!r}")
    known = _registry()  # a plug-in that does not load: one line here, in every command
    out: list[str] = []
    for item in items:
        if not isinstance(item, str) or not item.strip():
            raise ConfigError(f"{source}: an empty method name in {value!r} (known: {', '.join(known)})")
        item = item.strip()
        parts = [] if item in DERIVED else item.split(UNION_SEP)
        for p in parts:
            if p not in known:
                what = "an empty member" if not p else f"unknown method {p!r}"
                raise ConfigError(f"{source}: {what} in {item!r} (known: {', '.join(known)}; "
                                  f"unions as a+b; {', '.join(DERIVED)} of zcut and sor)")
        if item not in out:
            out.append(item)
    if not out:
        raise ConfigError(f"{source}: no method named (known: {', '.join(known)})")
    return tuple(out)


def base_methods(methods: Iterable[str]) -> tuple[str, ...]:
    """The base methods a list needs run, in registry order (``zcut`` always: the pipeline's own
    filter, whose cuts the viewer shows and SOR's ``top`` region uses)."""
    need = {"zcut"}
    for name in methods:
        need.update(members(name))
    return tuple(n for n in registry() if n in need)


def reported_methods(methods: Iterable[str]) -> tuple[str, ...]:
    """The methods a report lists: the config's, then ``union`` and ``intersection`` when both zcut
    and sor are among them (the report's fixed derived pair)."""
    ms = list(methods)
    if "zcut" in ms and "sor" in ms:
        ms += [d for d in DERIVED if d not in ms]
    return tuple(ms)


def method_mask(outliers: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """The mask of a reported method from the base methods' masks: a base name, a union ``a+b``,
    ``union`` (zcut | sor) or ``intersection`` (zcut & sor)."""
    if name in outliers:
        return outliers[name]
    if name == "intersection":
        return np.asarray(outliers["zcut"] & outliers["sor"])
    out = None
    for m in members(name):
        out = outliers[m].copy() if out is None else (out | outliers[m])
    assert out is not None
    return out


def method_masks(outliers: Mapping[str, np.ndarray], names: Iterable[str]) -> dict[str, np.ndarray]:
    """``{name: method_mask(outliers, name)}`` for every name."""
    return {n: method_mask(outliers, n) for n in names}
