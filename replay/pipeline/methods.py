"""The filter methods a replay runs and scores: one registry, so that every command knows the same names.

A *method* is a named outlier filter that judges the zone of a frame (the pixels the bin stages left,
:class:`replay.pipeline.stages.Zone`) and returns its outliers there. ``zcut`` (the paper's filter)
and ``sor`` (its comparison) are methods; so is every filter added to the bank. A method reads its
parameters from its own section of the resolved :class:`~replay.pipeline.config.PipelineConfig`
(``config.zcut``, ``config.sor``, ...), never from loose keywords.

The config's ``methods`` list (``--methods`` on the command line) names the methods a command runs,
reports and scores, and unions of them written ``a+b`` (e.g. ``zcut+mixed_pixel``): a union is
derived from the masks of its members, never run on its own. ``union`` and ``intersection`` are the
report's two derived methods of ``zcut`` and ``sor`` (docs/accuracy.md), present whenever both are.

Adding a filter is one :class:`Method` entry in :func:`registry` and one parameter section in the
config (``replay.pipeline.config.STAGE_SECTIONS``).

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

import types
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from replay.errors import ConfigError

#: The methods a config runs when it names none: the paper's filter and its comparison.
DEFAULT_METHODS: tuple[str, ...] = ("zcut", "sor")
#: The report's derived methods of ``zcut`` and ``sor`` (present whenever both are).
DERIVED: tuple[str, ...] = ("union", "intersection")
#: Joins the members of a union (``zcut+mixed_pixel``).
UNION_SEP = "+"


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


@dataclass(frozen=True, slots=True)
class Method:
    """One filter of the registry.

    Attributes
    ----------
    name : str
        The name in ``methods`` lists, reports and tables.
    section : str
        The config section holding its parameters.
    summary : str
        One line for ``--help`` and the docs.
    run : callable
        ``run(frame, zone, config) -> MethodOutput``: the frame (``replay.logs.frame.Frame``), its
        zone (``replay.pipeline.stages.Zone``) and the resolved config.
    needs_intrinsics : bool
        It needs the camera model (a log without one gets a named warning and no outliers).
    """

    name: str
    section: str
    summary: str
    run: Callable[..., MethodOutput]
    needs_intrinsics: bool = False


def _run_zcut(frame, zone, config) -> MethodOutput:
    from zcut.cuts import find_clusters

    cut = find_clusters(zone.height_mm, params=config.zcut)
    return MethodOutput(cut.outliers & zone.zone, cut)


def _run_sor(frame, zone, config) -> MethodOutput:
    from replay.pipeline.stages import sor_on_zone

    if not config.sor.enabled:
        return MethodOutput(np.zeros_like(zone.zone), warning="SOR disabled (sor.enabled = false)")
    return MethodOutput(sor_on_zone(frame, zone, config))


def _in_zone(zone, mask: np.ndarray) -> MethodOutput:
    return MethodOutput(mask & zone.zone)


def _run_radius(frame, zone, config) -> MethodOutput:
    from replay.pipeline.stages import zone_crop
    from zcut.radius import radius_stage

    out = np.zeros_like(zone.zone)
    crop = zone_crop(frame.xyz, zone.zone, whole=zone.removal is None)
    if crop is not None:
        sl, sub = crop
        out[sl] = radius_stage(sub, params=config.radius) & zone.zone[sl]
    return MethodOutput(out)


def _run_cluster(frame, zone, config) -> MethodOutput:
    from zcut.components import cluster_stage

    return _in_zone(zone, cluster_stage(frame.xyz, params=config.cluster, intrinsics=frame.intrinsics))


def _run_speckle(frame, zone, config) -> MethodOutput:
    from zcut.components import speckle_stage

    return _in_zone(zone, speckle_stage(frame.xyz, params=config.speckle))


def _run_window(frame, zone, config) -> MethodOutput:
    from zcut.local_rules import window_stage

    return _in_zone(zone, window_stage(frame.xyz, params=config.window))


def _run_mixed_pixel(frame, zone, config) -> MethodOutput:
    from zcut.local_rules import mixed_pixel_stage

    return _in_zone(zone, mixed_pixel_stage(frame.xyz, params=config.mixed_pixel))


def suspect_params(config) -> Any:
    """The config's :class:`~zcut.params.SuspectParams`, with the z-cut's a_max when its own is not set."""
    import dataclasses

    p = config.suspects
    if p.a_max is None and config.zcut.a_max is not None:
        p = dataclasses.replace(p, a_max=config.zcut.a_max)
    return p


def _run_suspects(frame, zone, config) -> MethodOutput:
    from zcut.suspects import suspects

    K = frame.intrinsics
    if K is not None and (K.height, K.width) != tuple(zone.zone.shape):
        K = None  # the size check is the frame reader's; the detectors need nothing else from the camera
    res = suspects(frame.xyz, zone.height_mm, zone.zone, zone.easy, params=suspect_params(config), intrinsics=K)
    return MethodOutput(res.mask & zone.zone, res)


def registry() -> Mapping[str, Method]:
    """Every method zcut knows, by name (a read-only mapping, built anew on each call)."""
    methods = (
        Method("zcut", "zcut", "the paper's z-cut: floating clusters smaller than μ_thr, found by descending cuts",
               _run_zcut),
        Method("sor", "sor", "statistical outlier removal, the paper's comparison (PCL / MATLAB pcdenoise)",
               _run_sor),
        Method("radius", "radius", "radius outlier removal: too few other points within a ball (Open3D, PCL)",
               _run_radius),
        Method("cluster", "cluster", "cluster removal: small 3D-connected groups of pixels, by area in mm² (Zivid)",
               _run_cluster, needs_intrinsics=True),
        Method("speckle", "speckle", "speckle removal: small regions cut off by depth jumps (OpenCV, Ensenso)",
               _run_speckle),
        Method("window", "window", "3 × 3 window rule: too few neighbours within a relative depth tolerance (Basler)",
               _run_window),
        Method("mixed_pixel", "mixed_pixel", "mixed pixels: the surface leaves the pixel along its ray (ifm)",
               _run_mixed_pixel),
        Method("suspects", "suspects", "the labelling page's suspects: every detector of zcut.suspects, united "
               "(not a filter to ship)", _run_suspects),
    )
    return types.MappingProxyType({m.name: m for m in methods})


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
        An empty list, an unknown name (naming the known ones), an empty member (``zcut+``).
    """
    if isinstance(value, str):
        items = [v.strip() for v in value.split(",")]
    elif isinstance(value, (list, tuple)):
        items = list(value)
    else:
        raise ConfigError(f"{source} must be a list of method names, got {value!r}")
    known = registry()
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
        return outliers["zcut"] & outliers["sor"]
    out = None
    for m in members(name):
        out = outliers[m].copy() if out is None else (out | outliers[m])
    assert out is not None
    return out


def method_masks(outliers: Mapping[str, np.ndarray], names: Iterable[str]) -> dict[str, np.ndarray]:
    """``{name: method_mask(outliers, name)}`` for every name."""
    return {n: method_mask(outliers, n) for n in names}
