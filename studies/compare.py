"""``zcut compare``: two filters (configs, method names or results files) on the same frames, pixel by
pixel, with a paired verdict (docs/compare.md).

A library call, in named steps::

    result = run(CompareOptions(logs=(log,), a="zcut", b="tuned.toml", out=Path("cmp")))
    #   sides = side_spec(a), side_spec(b)          what A and B are (config, method, results file)
    #   plan_logs, resolve_log                      the driver: hash and split every log into units (as
    #                                               `zcut batch`), resolve both configs once per log
    #   PartStore(out, identity)                    resumable: units done in DIR are not run again
    #   execute(units, run_compare_unit)            per unit (local processes, Ray or this process):
    #     _frames_of_log                            run each frame once, sharing every stage whose
    #                                               parameters A and B share
    #     _score_frame                              the counts `zcut accuracy` gives each side, the
    #                                               agreement of the two masks, the disagreement blobs
    #   _Assembler.advance                          the one writer, after each unit: every frame whose
    #                                               units before it are done, in log order, into
    #                                               compare.rrd and the npz
    #   _Assembler.finish                           the verdict (pooled figures, paired Δ, sign test),
    #                                               compare.json, summary.parquet, report.html

Sharing. Both sides run on the frames read once. When A's and B's ``bin_mask``, ``registration`` and
``removal`` sections are equal, the bin stages (:func:`replay.pipeline.stages.locate_bin`) run once and
the zone (:func:`~replay.pipeline.stages.bin_zone`) is B's too (also when ``zcut.max_depth`` is equal:
the bin check's band); each base method whose parameters are equal on both sides (its own section,
and ``zcut`` for ``sor`` and ``suspects``, which read it) runs once on that zone and is handed to the
other side (:func:`~replay.pipeline.stages.judge_zone`'s ``done``). The masks are then exactly those
of two separate replays, and the counts those of two separate ``zcut accuracy`` runs.

Primary methods. A side's *primary* method is the first of its config's ``methods`` (a method name:
that method; a results file: ``zcut``); when both configs run the same methods, the first of them
whose parameters differ (:func:`primary_methods`). The verdict compares A's primary with B's. Every
method both sides report is also compared (``per_method``).

Scale. The work runs in the units of a study (:mod:`studies.driver`, as ``zcut batch``): whole chunks of
one log (``frames_per_unit``), on local worker processes (``workers``), a Ray cluster (``ray``) or this
process (``workers=0``). Each unit returns per frame its :class:`FrameCompare` and the images the writer
needs (:data:`studies.compare_records.PART_COLUMNS`), kept in ``DIR/parts`` as it finishes; a rerun over
the same DIR runs only the units not done (another config, log set or option is refused, one line). The
one writer takes the frames in log order, each as soon as the units before it are done (the recording
grows while the units run), so every output equals that of one process running the frames one after
another.

No argparse here: ``cli/commands/compare.py`` is the command.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections import Counter
from collections.abc import Generator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.errors import ConfigError
from studies.compare_records import (  # noqa: F401 - the records are part of this module's API
    Blob,
    FrameCompare,
    FrameImages,
    SideFrame,
    SideSpec,
    count_f1,
    frame_from_json,
    frame_to_json,
    part_schema,
    summary_rows,
)
from zcut.errors import ZcutError

if TYPE_CHECKING:
    from contextlib import ExitStack

    from replay.logs.frame import Frame
    from replay.pipeline.config import PipelineConfig, Resolved
    from studies.driver import LogPlan
    from studies.executors import Executor
    from studies.parts import PartStore
    from studies.units import WorkUnit
    from studies.work import Job, UnitResult
    from zcut.paired import Counts

#: The bin stages' config sections: equal on both sides, they run once.
BIN_SECTIONS = ("bin_mask", "registration", "removal")
#: Per-pixel codes of the difference image (``diff/consequence`` in the recording, docs/compare.md).
DIFF_CODES: dict[int, str] = {1: "B fixes", 2: "B breaks", 3: "both wrong", 4: "removed only by A",
                              5: "removed only by B"}
#: Blobs kept per frame in compare.json (the largest; every blob is counted).
MAX_BLOBS_PER_FRAME = 50
#: Frames per unit of work (whole chunks of one log), as ``zcut batch``'s.
FRAMES_PER_UNIT = 8
#: How a comparison opens its logs: each frame's true depth decoded from the chunk the pass reads anyway
#: (the displacement classes: :func:`annotate.accuracy.displacement_mm`), not read from the log again.
READER_OPTIONS = {"truth_depth": True}


class CompareError(ZcutError, ValueError):
    """Bad input to a comparison (one line naming what is wrong)."""


def side_spec(text: str, *, label: str) -> SideSpec:
    """Parse ``--a`` / ``--b``: an existing ``.mcap`` is a results file, another existing file a config
    (TOML), else a method name (``zcut``, ``sor``, ``radius``, a union ``zcut+sor``, ...).

    Raises
    ------
    CompareError
        Neither a file nor a known method (naming the known ones); a config that is not valid.
    """
    from replay.pipeline import config as cfg
    from replay.pipeline.methods import parse_methods, registry

    p = Path(text)
    if p.is_file():
        if p.suffix == ".mcap":
            return SideSpec(label, text, "results", p, {})
        try:
            return SideSpec(label, text, "config", p, cfg.load_toml(p))
        except ConfigError as e:
            raise CompareError(f"--{label.lower()}: {e}") from None
    if os.sep in text or text.endswith((".toml", ".mcap")):
        raise CompareError(f"--{label.lower()} {text}: no such file")
    try:
        methods = parse_methods(text, source=f"--{label.lower()}")
    except ConfigError:
        raise CompareError(f"--{label.lower()} {text!r}: neither a file nor a method name (methods: "
                           f"{', '.join(registry())}; unions as a+b)") from None
    if len(methods) != 1:
        raise CompareError(f"--{label.lower()} {text!r}: one method name (a config file runs several)")
    return SideSpec(label, text, "method", None, {"methods": list(methods)})


@dataclass(frozen=True, slots=True)
class CompareOptions:
    """What to compare and where to write it (``zcut compare``'s options).

    Attributes
    ----------
    logs : tuple of Path
    a, b : str
        Each a config file, a method name or a results file (:func:`side_spec`).
    out : Path
        Output folder (created).
    labels, annotator : truth from an annotator's labels (default: the log's recorded truth)
    truth : {"paper", "sensor"} or None
        The log's recorded truth to score against (docs/accuracy.md, "Two truths"; None: the paper's
        where the log has it, else the sensor's); not with ``labels``.
    region : {"zone", "valid"}
    bin_model, topic : as ``zcut replay``'s
    part_model, part_model_unit : the part's mesh of the method ``explained`` (as ``zcut replay
        --part-model``); without it the log's own ``part_model.ply``
    frames : (start, stop)
    force : bool
        Replace existing outputs.
    rrd, report : bool
        Write ``compare.rrd`` and ``report.html``.
    level : float
        Confidence level of the intervals.
    workers : int or None
        Local worker processes (None: the cores, as many as the free memory holds; 0: this process,
        one unit after another), as ``zcut batch``'s.
    ray : str or None
        A Ray cluster's address, or ``auto``, instead of local processes.
    frames_per_unit : int
        Frames per unit of work (whole chunks of one log).
    """

    logs: tuple[Path, ...]
    a: str
    b: str
    out: Path
    labels: Path | None = None
    annotator: str | None = None
    region: str = "zone"
    bin_model: Path | None = None
    topic: str | None = None
    part_model: Path | None = None
    part_model_unit: str = "mm"
    frames: tuple[int, int | None] = (0, None)
    force: bool = False
    rrd: bool = True
    report: bool = True
    truth: str | None = None
    level: float = 0.95
    workers: int | None = None
    ray: str | None = None
    frames_per_unit: int = FRAMES_PER_UNIT


@dataclass(slots=True)
class CompareResult:
    """What a comparison found and wrote (``compare.json`` is :attr:`report`)."""

    report: dict[str, Any]
    frames: list[FrameCompare]
    outputs: dict[str, str] = field(default_factory=dict)
    stage_runs: Counter[str] = field(default_factory=Counter)
    data_loss: bool = False


# ------------------------------------------------------------------------------------- the engine
def _method_sections(name: str) -> tuple[str, ...]:
    """The config sections a base method reads."""
    from replay.pipeline.methods import registry

    section = registry()[name].section
    return (section, "zcut") if name in ("sor", "suspects") else (section,)


def shared_methods(a: PipelineConfig, b: PipelineConfig) -> tuple[str, ...]:
    """The base methods both configs run with the same parameters (they run once on a shared zone)."""
    return tuple(m for m in b.base_methods if m in a.base_methods
                 and all(getattr(a, s) == getattr(b, s) for s in _method_sections(m)))


def shares_cut_tree(a: PipelineConfig, b: PipelineConfig) -> bool:
    """Both configs run the z-cut and its tree is the same (the same Δd, number of cuts and connectivity:
    :class:`zcut.cuts.StageTree`); their ``max_area`` (ρ_thr) or ``a_max`` may differ."""
    from replay.pipeline.methods import registry

    za, zb = a.zcut, b.zcut
    builtin = registry()["zcut"].run.__module__ == "replay.pipeline.methods"
    return (builtin and "zcut" in a.base_methods and "zcut" in b.base_methods and za.step == zb.step
            and za.n_levels == zb.n_levels and za.connectivity == zb.connectivity)


def same_bin_stages(a: PipelineConfig, b: PipelineConfig) -> bool:
    return all(getattr(a, s) == getattr(b, s) for s in BIN_SECTIONS)


def primary_methods(a: PipelineConfig | None, b: PipelineConfig | None) -> tuple[str, str]:
    """The methods the verdict compares (docs/compare.md): each config's first method (a results
    file's: ``zcut``); when both configs run the same methods on the same zone, the first of them
    whose parameters differ (two configs that differ only in SOR compare SOR).

    Raises
    ------
    CompareError
        Both configs run the same methods with the same parameters on the same zone: their masks
        cannot differ.
    """
    from replay.pipeline.methods import members

    pa = a.methods[0] if a is not None else "zcut"
    pb = b.methods[0] if b is not None else "zcut"
    if a is None or b is None or not (same_bin_stages(a, b) and a.zcut.max_depth == b.zcut.max_depth):
        return pa, pb
    if a.methods == b.methods:
        for m in a.methods:
            if any(getattr(a, s) != getattr(b, s) for base in members(m) for s in _method_sections(base)):
                return m, m
    elif pa != pb or any(getattr(a, s) != getattr(b, s) for base in members(pa) for s in _method_sections(base)):
        return pa, pb
    diff = ", ".join(d["key"] for d in config_difference(a, b)) or "nothing"
    raise CompareError(f"A and B run {pa} with the same parameters on the same zone: its masks cannot differ "
                       f"(the configs differ in {diff})")


def config_difference(a: PipelineConfig, b: PipelineConfig) -> list[dict[str, Any]]:
    """The parameters that differ between two resolved configs: ``[{"key", "a", "b"}]`` (``section.key``,
    in the config file's keys; a value missing on one side is None)."""
    from replay.pipeline import config as cfg

    da, db = cfg.to_dict(a), cfg.to_dict(b)
    out = []
    for k in dict.fromkeys([*da, *db]):
        va, vb = da.get(k), db.get(k)
        if isinstance(va, dict) or isinstance(vb, dict):
            va, vb = va or {}, vb or {}
            for kk in dict.fromkeys([*va, *vb]):
                if va.get(kk) != vb.get(kk):
                    out.append({"key": f"{k}.{kk}", "a": va.get(kk), "b": vb.get(kk)})
        elif va != vb:
            out.append({"key": k, "a": va, "b": vb})
    return out


class PairRunner:
    """Both configs on the frames of one log, each stage run once where A and B share it.

    ``runs`` counts the stage calls made (``locate_bin``, ``bin_zone``, ``method:NAME``), so that a
    test and the report can see what was shared.
    """

    def __init__(self, path: Path, reader: Any, first: Frame, resolved_a: Resolved, resolved_b: Resolved,
                 bin_model: Any, runs: Counter[str] | None = None) -> None:
        from replay.pipeline.session import ReplaySession

        self.a, self.b = resolved_a.config, resolved_b.config
        self.session_a = ReplaySession(path, reader, resolved_a, bin_model, first)
        self.same_locate = same_bin_stages(self.a, self.b)
        self.same_zone = self.same_locate and self.a.zcut.max_depth == self.b.zcut.max_depth
        self.session_b = self.session_a if self.same_locate else ReplaySession(path, reader, resolved_b, bin_model,
                                                                                first)
        self.shared = shared_methods(self.a, self.b) if self.same_zone else ()
        self.runs: Counter[str] = Counter() if runs is None else runs
        #: A's and B's z-cuts differ only in what re-tags one tree (:func:`shares_cut_tree`): B's is
        #: answered from A's tree (:class:`zcut.cuts.StageTree`), the same result as its own.
        self.share_tree = self.same_zone and "zcut" not in self.shared and shares_cut_tree(self.a, self.b)
        #: The z-cut trees built, when :attr:`share_tree` (one a frame).
        self.trees = 0

    def frames(self, frames: tuple[int, int | None]) -> Generator[tuple[Any, Any, Any], None, None]:
        """``(frame, result_a, result_b)`` of every readable frame; the stream (for its damage) is
        :attr:`stream` once started."""
        self.stream = self.session_a.located(frames=frames, config=self.a)
        return self._frames(self.stream)

    def _frames(self, located: Any) -> Generator[tuple[Any, Any, Any], None, None]:
        from replay.pipeline.stages import bin_zone, judge_zone, locate_bin, run_methods

        sa, sb = self.session_a, self.session_b
        try:
            for frame, future in located:
                t0 = time.perf_counter()
                loc_a = future.result()
                self.runs["locate_bin"] += 1
                if self.same_locate:
                    loc_b = loc_a
                else:
                    loc_b = locate_bin(frame, self.b, bin_model=sb.prepared, seed=sb.seed)
                    self.runs["locate_bin"] += 1
                zone_a = bin_zone(frame, self.a, bin_model=sa.prepared, located=loc_a)
                self.runs["bin_zone"] += 1
                if self.same_zone:
                    zone_b = zone_a
                else:
                    zone_b = bin_zone(frame, self.b, bin_model=sb.prepared, located=loc_b)
                    self.runs["bin_zone"] += 1
                timings: dict[str, float] = {}
                cuts = self._shared_cuts(zone_a) if self.share_tree else None
                found = run_methods(frame, zone_a, self.a, timings=timings, warnings=[],
                                    done=None if cuts is None else {"zcut": cuts[0]})
                for m in found:
                    self.runs[f"method:{m}"] += 1
                done_a = {m: (found[m], timings[m]) for m in found}
                res_a = judge_zone(frame, zone_a, self.a, t_start=t0, done=done_a)
                t1 = time.perf_counter()
                done_b = {m: done_a[m] for m in self.shared}
                for m in self.b.base_methods:
                    if m not in done_b:
                        self.runs[f"method:{m}"] += 1  # B's z-cut from A's tree too: its own answer
                if cuts is not None:
                    done_b["zcut"] = cuts[1]
                res_b = judge_zone(frame, zone_b, self.b, t_start=t1, done=done_b)
                yield frame, res_a, res_b
                # this frame's arrays freed before the next frame's are made: the allocator hands their
                # memory to the next frame (fresh pages are page faults: system time)
                del frame, future, loc_a, loc_b, zone_a, zone_b, found, done_a, done_b, res_a, res_b, cuts
        finally:
            located.close()

    def _shared_cuts(self, zone: Any) -> tuple[tuple[Any, float], tuple[Any, float]] | None:
        """A's and B's z-cut outputs on one zone from one tree (``{"zcut": (output, seconds)}`` of
        :func:`~replay.pipeline.stages.run_methods`'s ``done``, as the method ``zcut`` makes them:
        :func:`zcut.cuts.find_clusters` masked by the zone); None when the z-cut refuses the zone (each
        side then runs it and reports the refusal as a replay does)."""
        from replay.pipeline.methods import MethodOutput
        from zcut.cuts import StageTree

        t0 = time.perf_counter()
        try:
            tree = StageTree(zone.height_mm, params=self.a.zcut)
            cut_a = tree.answer(self.a.zcut)
            t1 = time.perf_counter()
            cut_b = tree.answer(self.b.zcut)
        except ZcutError:
            return None
        t2 = time.perf_counter()
        self.trees += tree.trees
        return ((MethodOutput(cut_a.outliers & zone.zone, cut_a), t1 - t0),
                (MethodOutput(cut_b.outliers & zone.zone, cut_b), t2 - t1))


# ------------------------------------------------------------------------------------ one log
@dataclass(slots=True)
class _Log:
    path: Path
    resolved_a: Any = None
    resolved_b: Any = None
    diff: list[dict[str, Any]] = field(default_factory=list)
    damage: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    shared: dict[str, Any] = field(default_factory=dict)
    n_frames: int = 0
    n_unscored: int = 0
    intrinsics: Any = None
    primaries: tuple[str, str] = ("zcut", "zcut")
    part_kind: str = "unknown"


@dataclass(frozen=True, slots=True)
class LogSides:
    """Both sides of one log as the driver resolved them; a unit runs exactly these (never resolves again).

    Attributes
    ----------
    resolved : dict
        ``"A"`` / ``"B"`` -> :class:`~replay.pipeline.config.Resolved` of a config or method side.
    configs : dict
        ``"A"`` / ``"B"`` -> its config (a results file's from its metadata, None when unknown).
    primaries : (str, str)
        The methods the verdict compares (:func:`primary_methods`).
    diff : list of dict
        :func:`config_difference` (empty without both configs).
    shared : dict
        What runs once for both: ``bin_stages``, ``zone``, ``methods`` (as :class:`PairRunner` shares).
    part_kind : str
        The log's part kind as its metadata says it (a synthetic log's ``zcut.synth`` ``part_kind``:
        ``rods``, ``empty``, ...), ``unknown`` when it does not.
    """

    resolved: dict[str, Any]
    configs: dict[str, Any]
    primaries: tuple[str, str]
    diff: list[dict[str, Any]]
    shared: dict[str, Any]
    part_kind: str = "unknown"


def resolve_log(opts: CompareOptions, spec_a: SideSpec, spec_b: SideSpec, path: Path, reader: Any, first: Frame,
                ) -> LogSides:
    """Resolve A and B for one log (``reader``, its ``first`` readable frame), check that they differ and
    that a results file is this log's; one line of :class:`CompareError` otherwise."""
    from replay.pipeline import config as cfg
    from replay.pipeline.explained import with_log_part_model, with_part_model

    facts = cfg.log_facts(reader.metadata, first, intrinsics=getattr(reader, "intrinsics", None))
    resolved: dict[str, Any] = {}
    configs: dict[str, Any] = {}
    for spec in (spec_a, spec_b):
        if spec.kind == "results":
            meta, _, _ = _results_masks(spec, path)
            configs[spec.label] = _results_config(meta, spec)
        else:
            file_layer = spec.layer if spec.kind == "config" else None
            cli = spec.layer if spec.kind == "method" else None
            side = cfg.resolve(facts, file_layer=file_layer, cli=cli)
            if opts.part_model is not None and "explained" in side.config.base_methods:
                side = with_part_model(side, opts.part_model, unit=opts.part_model_unit)
            resolved[spec.label] = with_log_part_model(side, path, reader)
            configs[spec.label] = resolved[spec.label].config
    primaries = _check_differ(spec_a, spec_b, configs["A"], configs["B"], path)
    diff = config_difference(configs["A"], configs["B"]) if configs["A"] is not None and configs["B"] is not None else []
    shared: dict[str, Any] = {"bin_stages": False, "zone": False, "methods": []}
    if len(resolved) == 2:
        a, b = resolved["A"].config, resolved["B"].config
        same_locate = same_bin_stages(a, b)
        same_zone = same_locate and a.zcut.max_depth == b.zcut.max_depth
        shared = {"bin_stages": same_locate, "zone": same_zone,
                  "methods": list(shared_methods(a, b)) if same_zone else []}
    return LogSides(resolved, configs, primaries, diff, shared, log_part_kind(reader.metadata))


def log_part_kind(metadata: dict[str, dict[str, str]]) -> str:
    """A log's part kind as its metadata says it (``zcut.synth``'s ``part_kind``), else ``unknown``."""
    from replay.logs import layout

    return metadata.get(layout.SYNTH_METADATA, {}).get("part_kind") or "unknown"


def _results_masks(spec: SideSpec, log: Path) -> tuple[dict[str, Any], dict[int, dict[str, np.ndarray]], tuple[str, ...]]:
    """A results file's (metadata record, masks by stamp, the base methods it holds); refused when it
    is the results of another log."""
    from replay.logs import layout
    from replay.logs.reader import read_mask_topics
    from replay.pipeline.methods import registry

    assert spec.path is not None
    wanted = tuple(layout.method_topic(m) for m in registry()) + (layout.ZONE,)
    try:
        metadata, masks = read_mask_topics(spec.path, wanted)
    except ZcutError as e:
        raise CompareError(f"--{spec.label.lower()} {spec.path}: {e}") from None
    meta = metadata.get(layout.RESULTS_METADATA)
    if meta is None:
        raise CompareError(f"--{spec.label.lower()} {spec.path}: not a results file of `zcut replay --out` "
                           f"(no {layout.RESULTS_METADATA} metadata)")
    source = meta.get("source")
    if source is not None and source != log.name:
        raise CompareError(f"--{spec.label.lower()} {spec.path}: the results of {source}, not of {log.name}")
    held = tuple(m for m in registry() if any(layout.method_topic(m) in f for f in masks.values()))
    if "zcut" not in held:
        raise CompareError(f"--{spec.label.lower()} {spec.path}: holds no {layout.ZCUT_OUTLIERS} masks")
    return meta, masks, held


def _results_config(meta: dict[str, Any], spec: SideSpec) -> PipelineConfig | None:
    """The config a results file was made with (its metadata's TOML), or None when unreadable."""
    import tomllib

    from replay.pipeline import config as cfg

    text = meta.get("config_toml")
    if not text:
        return None
    try:
        return cfg.from_dict(tomllib.loads(text), source=str(spec.path))
    except (ConfigError, tomllib.TOMLDecodeError, ValueError):
        return None


def _check_differ(spec_a: SideSpec, spec_b: SideSpec, ca: PipelineConfig | None, cb: PipelineConfig | None,
                  log: Path) -> tuple[str, str]:
    """The primary methods of the two sides; refuse two sides that run the same filter."""
    if spec_a.kind == "results" and spec_b.kind == "results":
        assert spec_a.path is not None and spec_b.path is not None
        if os.path.samefile(spec_a.path, spec_b.path):
            raise CompareError("--a and --b are the same results file: nothing to compare")
    from replay.pipeline import config as cfg

    if ca is not None and cb is not None and cfg.to_dict(ca) == cfg.to_dict(cb) and "results" not in (
            spec_a.kind, spec_b.kind):
        raise CompareError(f"--a {spec_a.name} and --b {spec_b.name} resolve to the same config for {log.name}: "
                           "they differ in nothing")
    try:
        return primary_methods(ca, cb)
    except CompareError as e:
        raise CompareError(f"--a {spec_a.name}, --b {spec_b.name} on {log.name}: {e}") from None


def _side_of_result(result: Any, methods: tuple[str, ...], region_name: str, *, other: SideFrame | None = None,
                    ) -> SideFrame:
    """One side of a frame from its pipeline result; ``other``: the other side's, whose scored region
    this side takes as it is (the same array) when both judged the same zone (A and B share their bin
    stages: the same zone and removal objects), rather than a copy of it."""
    from annotate.truth import method_predictions, scored_region

    o = other.result if other is not None else None
    same = o is not None and o.zone is result.zone and o.removal is result.removal and o.valid is result.valid
    region = other.region if same and other is not None else scored_region(result, region_name)
    return SideFrame(method_predictions(result, methods), result.valid, region, result)


def _side_of_masks(frame: Frame, masks: dict[str, np.ndarray] | None, held: tuple[str, ...], region_name: str,
                   ) -> SideFrame | None:
    from replay.logs import layout
    from replay.pipeline.methods import method_masks, reported_methods
    from zcut.removal import finite_xyz

    if masks is None:
        return None
    valid = finite_xyz(frame.xyz)
    base = {b: masks[layout.method_topic(b)] for b in held if layout.method_topic(b) in masks}
    if "zcut" not in base or base["zcut"].shape != valid.shape:
        return None
    region = valid
    if region_name == "zone" and layout.ZONE in masks:
        region = masks[layout.ZONE] & valid
    return SideFrame(method_masks(base, reported_methods(list(base))), valid, region)


#: What a worker process keeps of the logs it ran (its units usually come one log after another): the
#: opened log, its runner of A and B, a results file's masks; the last :data:`_MAX_KEPT` of each.
_KEPT: dict[tuple[Any, ...], Any] = {}
_MAX_KEPT = 6


def _kept(key: tuple[Any, ...], make: Any) -> Any:
    """``make()``, kept by this process under ``key`` (the oldest entries dropped)."""
    if key not in _KEPT:
        while len(_KEPT) >= _MAX_KEPT:
            _KEPT.pop(next(iter(_KEPT)))
        _KEPT[key] = make()
    return _KEPT[key]


def _open_unit_log(path: Path, sha256: str, topic: str | None) -> tuple[Any, Frame]:
    """The unit's log opened (reader, first readable frame), kept for the next unit of the same log."""
    from replay.pipeline.session import open_log

    def make() -> tuple[Any, Frame]:
        reader, first, _ = open_log(path, topic=topic, reader_options=READER_OPTIONS)
        return reader, first

    got: tuple[Any, Frame] = _kept(("log", str(path), sha256, topic), make)
    return got


def _frames_of_log(opts: CompareOptions, spec_a: SideSpec, spec_b: SideSpec, path: Path, sides: LogSides,
                   reader: Any, first: Frame, frames: tuple[int, int | None], runs: Counter[str], lost: list[Any],
                   sha256: str) -> Generator[tuple[Any, SideFrame | None, SideFrame | None], None, None]:
    """``(frame, side A, side B)`` of every readable frame of one log in ``frames`` (a side is None on a
    frame a results file does not hold); the stage calls are counted into ``runs``, the frames the
    stream lost (:class:`~replay.logs.damage.Damage`) added to ``lost`` when it ends. The runner of a
    log (its sessions, their prepared bin model) is kept for the next unit of the same log (every
    frame's registration starts from the log's first frame's pose: a frame's result does not depend
    on the frames run before it)."""
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.config import config_sha256

    region = opts.region
    resolved = sides.resolved
    results = {spec.label: _kept(("results", str(spec.path), str(path), sha256),
                                 lambda spec=spec: _results_masks(spec, path)[1:])
               for spec in (spec_a, spec_b) if spec.kind == "results"}
    model = None
    if opts.bin_model is not None:
        st = os.stat(opts.bin_model)
        model = (str(opts.bin_model), st.st_size, st.st_mtime_ns)
    key = ("runner", str(path), sha256, opts.topic, model,
           *(config_sha256(resolved[k].config) if k in resolved else None for k in "AB"))
    if len(resolved) == 2:
        runner: PairRunner = _kept(key, lambda: PairRunner(
            path, reader, first, resolved["A"], resolved["B"],
            bin_model_for(reader, opts.bin_model).model))
        runner.runs = runs
        it = runner.frames(frames)
        try:
            for frame, ra, rb in it:
                sa = _side_of_result(ra, runner.a.methods, region)
                yield frame, sa, _side_of_result(rb, runner.b.methods, region, other=sa)
                del frame, ra, rb, sa  # freed before the next frame (PairRunner._frames)
        finally:
            it.close()
            lost += runner.stream.damage
        return
    if len(resolved) == 1:
        from replay.pipeline.session import ReplaySession

        label = next(iter(resolved))
        session: ReplaySession = _kept(key, lambda: ReplaySession(
            path, reader, resolved[label], bin_model_for(reader, opts.bin_model).model, first))
        stream = session.results(frames=frames)
        other = "B" if label == "A" else "A"
        masks, held = results[other]
        try:
            for frame, r in stream:
                runs["locate_bin"] += 1
                runs["bin_zone"] += 1
                for m in r.outliers:
                    runs[f"method:{m}"] += 1
                mine = _side_of_result(r, resolved[label].config.methods, region)
                theirs = _side_of_masks(frame, masks.get(frame.stamp_ns), held, region)
                yield (frame, mine, theirs) if label == "A" else (frame, theirs, mine)
        finally:
            stream.close()
            lost += stream.damage
        return
    stream_f = reader.frames(start=frames[0], stop=frames[1])
    try:
        for frame in stream_f:
            found = [_side_of_masks(frame, results[s][0].get(frame.stamp_ns), results[s][1], region) for s in "AB"]
            yield frame, found[0], found[1]
    finally:
        stream_f.close()
        lost += stream_f.damage


# ------------------------------------------------------------------------------------ one frame
def _truth_source(opts: CompareOptions, log: Path, reader_topics: tuple[str, ...]) -> Any:
    from annotate.truth import LabelTruth, synthetic_truth

    if opts.labels is not None:
        return LabelTruth(opts.labels, log, annotator=opts.annotator)
    return synthetic_truth(opts.truth, reader_topics, log)


def pixel_footprint_mm2(xyz: np.ndarray, intrinsics: Any) -> np.ndarray | None:
    """(H, W) float64: the area one pixel covers at its depth, z² / (fx·fy) in mm² (NaN where invalid);
    None without a camera model."""
    if intrinsics is None or xyz.shape[:2] != (intrinsics.height, intrinsics.width):
        return None
    # z_mm * z_mm / (fx * fy), in place: the same operations in the same order (the same bits)
    out: np.ndarray = xyz[..., 2].astype(np.float64)
    out *= 1000.0
    np.multiply(out, out, out=out)
    out /= float(intrinsics.fx) * float(intrinsics.fy)
    return out


def diff_image(mask_a: np.ndarray, mask_b: np.ndarray, where: np.ndarray,
               truth: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(H, W) uint8 codes of :data:`DIFF_CODES` over ``where``: with truth (``(outliers, scored)``) the
    consequence of B against A (1 B fixes, 2 B breaks, 3 both wrong), else who removed a pixel alone
    (4 only A, 5 only B)."""
    out = np.zeros(mask_a.shape, dtype=np.uint8)
    only_a, only_b = mask_a & ~mask_b & where, mask_b & ~mask_a & where
    if truth is None:
        out[only_a] = 4
        out[only_b] = 5
        return out
    lab, scored = truth
    right_a = (mask_a == lab) & scored & where
    right_b = (mask_b == lab) & scored & where
    out[~right_a & right_b] = 1
    out[right_a & ~right_b] = 2
    out[~right_a & ~right_b & scored & where] = 3
    out[(only_a | only_b) & ~scored] = 0
    return out


#: The blobs' nearest kept pixels are searched in windows (:func:`_nearest_kept`): blobs are grouped by
#: the tile of this side (px) their box starts in, and each group's window is its blobs' box widened by
#: :data:`_MARGIN_PX` first (by more where that does not prove the answer).
_TILE_PX = 128
_MARGIN_PX = 8


def _nearest_kept(rows: np.ndarray, cols: np.ndarray, boxes: list[tuple[int, int, int, int, np.ndarray]],
                  kept_in: Any, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """For the pixels ``(rows[i], cols[i])``: the kept pixel that the Euclidean feature transform of the
    whole image (``scipy.ndimage.distance_transform_edt(~kept, return_indices=True)``) names nearest,
    found in windows of the image; None when nothing is kept in the image.

    ``boxes``: ``(r0, r1, c0, c1, idx)``, the pixels ``idx`` (indices into ``rows``) lie in rows
    ``r0:r1`` and columns ``c0:c1``; ``kept_in(r0, r1, c0, c1)`` the kept mask of a window.

    Why a window gives the whole image's answer. SciPy's transform (Maurer, Qi, Raghavan 2003;
    ``ni_morphology.c``, ``_VoronoiFT``) names, among the kept pixels at the smallest distance, the
    one of the smallest column, then of the smallest row: its first pass (along each column) keeps
    the upper of two equally near pixels (it moves on only to a strictly nearer one); its second
    (along each row) drops from the lower envelope only a column's candidate that is strictly
    farther than two others everywhere, so never a nearest one, and keeps the leftmost of equally
    near ones. Every distance it compares is a sum of squared integers, exact in float64. So the
    answer is a function of the set of nearest kept pixels, the same on any window holding that set.
    A window's answer q for a pixel p at squared distance d² is the whole image's when every pixel
    outside the window is strictly farther than d from p: then no kept pixel outside is as near as q,
    and the nearest set is the window's. That is checked for every pixel (its distance to the
    window's edges, none on a side where the window reaches the image's border); a pixel that fails
    is searched again in a window widened by more than d around it, where it passes. A window without
    a kept pixel is widened until it has one, or is the whole image (then nothing is kept at all).
    ``tests/studies/test_compare_blobs.py`` checks the rule against a brute-force search and the
    result against the whole image's transform.
    """
    from scipy import ndimage

    h, w = shape
    far = h * h + w * w + 1  # farther than any two pixels of the image
    qr = np.empty(rows.size, dtype=np.intp)
    qc = np.empty(rows.size, dtype=np.intp)
    todo = [(r0, r1, c0, c1, idx, _MARGIN_PX) for r0, r1, c0, c1, idx in boxes]
    while todo:
        r0, r1, c0, c1, idx, m = todo.pop()
        a0, a1, b0, b1 = max(r0 - m, 0), min(r1 + m, h), max(c0 - m, 0), min(c1 + m, w)
        kept = kept_in(a0, a1, b0, b1)
        if not kept.any():
            if (a0, a1, b0, b1) == (0, h, 0, w):
                return None
            todo.append((r0, r1, c0, c1, idx, 2 * m + 1))
            continue
        ri, ci = ndimage.distance_transform_edt(~kept, return_distances=False, return_indices=True)
        pr, pc = rows[idx] - a0, cols[idx] - b0
        gr, gc = ri[pr, pc].astype(np.intp), ci[pr, pc].astype(np.intp)
        d2 = (gr - pr) ** 2 + (gc - pc) ** 2
        edge = np.full(idx.size, far, dtype=np.intp)  # the nearest pixel outside the window, squared
        for side, dist in ((a0 > 0, pr + 1), (a1 < h, a1 - a0 - pr), (b0 > 0, pc + 1), (b1 < w, b1 - b0 - pc)):
            if side:
                np.minimum(edge, dist * dist, out=edge)
        ok = d2 < edge
        qr[idx[ok]] = gr[ok] + a0
        qc[idx[ok]] = gc[ok] + b0
        if not ok.all():
            bad = idx[~ok]
            grow = int(np.ceil(np.sqrt(float(d2[~ok].max())))) + 1
            todo.append((int(rows[bad].min()), int(rows[bad].max()) + 1, int(cols[bad].min()),
                         int(cols[bad].max()) + 1, bad, grow))
    return qr, qc


def _blob_boxes(box: np.ndarray, gid: np.ndarray, offset: int) -> list[tuple[int, int, int, int, np.ndarray]]:
    """Windows of :func:`_nearest_kept` for one side's blobs: the blobs grouped by the tile their box
    starts in (``box``: (n, 4) int64, each blob's rows ``box[:, 0]:box[:, 1]`` and columns
    ``box[:, 2]:box[:, 3]``, as :func:`scipy.ndimage.find_objects` gives them; ``gid`` each pixel's blob,
    0-based), each group's box and its pixels (indices offset by ``offset``)."""
    keys, blob_group = np.unique((box[:, 0] // _TILE_PX) * (1 << 32) + box[:, 2] // _TILE_PX, return_inverse=True)
    blob_group = blob_group.ravel()
    by_group = np.argsort(blob_group, kind="stable")
    first = np.searchsorted(blob_group[by_group], np.arange(keys.size))
    lo = np.minimum.reduceat(box[by_group], first, axis=0)
    hi = np.maximum.reduceat(box[by_group], first, axis=0)
    group = blob_group[gid]
    order = np.argsort(group, kind="stable") + offset
    bounds = np.searchsorted(group, np.arange(keys.size + 1), sorter=order - offset)
    return [(int(lo[g, 0]), int(hi[g, 1]), int(lo[g, 2]), int(hi[g, 3]), order[bounds[g]:bounds[g + 1]])
            for g in range(keys.size)]


def _boxes_of(n: int, rows: np.ndarray, cols: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(n, 4) int64: each component's ``(row0, row1, col0, col1)`` (ends exclusive) from its pixels
    (``ids`` 1..n), the boxes of ``scipy.ndimage.find_objects``."""
    box = np.empty((n, 4), dtype=np.int64)
    box[:, 0] = box[:, 2] = np.iinfo(np.int64).max
    box[:, 1] = box[:, 3] = -1
    k = ids - 1
    np.minimum.at(box[:, 0], k, rows)
    np.maximum.at(box[:, 1], k, rows)
    np.minimum.at(box[:, 2], k, cols)
    np.maximum.at(box[:, 3], k, cols)
    box[:, 1] += 1
    box[:, 3] += 1
    return box


def _footprint_at(xyz: np.ndarray, intrinsics: Any, rows: np.ndarray, cols: np.ndarray) -> np.ndarray | None:
    """:func:`pixel_footprint_mm2` at the pixels ``(rows, cols)`` alone (the same operations on the same
    values: the same bits); None where it gives None."""
    if intrinsics is None or xyz.shape[:2] != (intrinsics.height, intrinsics.width):
        return None
    out: np.ndarray = xyz[rows, cols, 2].astype(np.float64)
    out *= 1000.0
    np.multiply(out, out, out=out)
    out /= float(intrinsics.fx) * float(intrinsics.fy)
    return out


def disagreement_blobs(log: str, index: int, stamp_ns: int, mask_a: np.ndarray, mask_b: np.ndarray,
                       where: np.ndarray, *, truth: tuple[np.ndarray, np.ndarray] | None = None,
                       footprint: np.ndarray | None = None, xyz: np.ndarray | None = None,
                       intrinsics: Any = None) -> list[Blob]:
    """The 8-connected components of the pixels only A removed and of those only B removed (over
    ``where``), with area, centroid, with truth (``(outliers, scored)``) what B's choice did there,
    and with the frame's points ``xyz`` (metres, NaN invalid) its height above the local surface and
    its distance to the nearest kept point (:class:`Blob`): the nearest pixel, in the image, that
    neither side removed in ``where`` and whose point is valid, as the whole image's Euclidean feature
    transform names it (found in windows around the blobs: :func:`_nearest_kept`). The area in mm² is
    the sum of ``footprint`` over a blob's pixels (:func:`pixel_footprint_mm2`), or, given the camera's
    ``intrinsics`` instead, of the same figure computed at the blobs' pixels alone."""
    from annotate.accuracy import components8
    from zcut.removal import finite_xyz

    sides = []
    w = mask_a.shape[1]
    for who, m in (("A", mask_a & ~mask_b & where), ("B", mask_b & ~mask_a & where)):
        # the components as scipy.ndimage.label numbers them, found among the pixels (row-major) alone
        n, at, ids = components8(m)
        if n == 0:
            continue
        rows, cols = np.divmod(at, w)
        sides.append((who, n, rows, cols, ids))
    near = None
    if xyz is not None and sides:
        boxes = []
        offset = 0
        for _, n, rows, cols, ids in sides:
            boxes += _blob_boxes(_boxes_of(n, rows, cols, ids), ids - 1, offset)
            offset += rows.size
        m = 2 * _MARGIN_PX
        if sum((r1 - r0 + m) * (c1 - c0 + m) for r0, r1, c0, c1, _ in boxes) > mask_a.size // 2:
            boxes = [(0, mask_a.shape[0], 0, mask_a.shape[1], np.arange(offset))]  # the windows would cover it

        def kept_in(r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
            win = (slice(r0, r1), slice(c0, c1))
            out: np.ndarray = where[win] & ~mask_a[win] & ~mask_b[win] & finite_xyz(xyz[win])
            return out

        near = _nearest_kept(np.concatenate([s[2] for s in sides]), np.concatenate([s[3] for s in sides]), boxes,
                             kept_in, mask_a.shape)
    blobs: list[Blob] = []
    offset = 0
    for who, n, rows, cols, ids in sides:
        area = np.bincount(ids, minlength=n + 1)[1:]
        r = np.bincount(ids, weights=rows, minlength=n + 1)[1:] / np.maximum(area, 1)
        c = np.bincount(ids, weights=cols, minlength=n + 1)[1:] / np.maximum(area, 1)
        mm2 = None
        fp = None
        if footprint is not None:
            fp = footprint[rows, cols]  # only the blobs' pixels are read
        elif intrinsics is not None and xyz is not None:
            fp = _footprint_at(xyz, intrinsics, rows, cols)
        if fp is not None:
            mm2 = np.bincount(ids, weights=np.where(np.isfinite(fp), fp, 0.0), minlength=n + 1)[1:]
        if truth is not None:
            outl, scored = truth[0][rows, cols], truth[1][rows, cols]  # read at the blobs' pixels alone
            # B removed it alone: right where it is a true outlier; A removed it alone: B right where it is not
            good = (outl if who == "B" else ~outl) & scored
            bad = (~outl if who == "B" else outl) & scored
            fixes = np.bincount(ids, weights=good, minlength=n + 1)[1:].astype(np.int64)
            breaks = np.bincount(ids, weights=bad, minlength=n + 1)[1:].astype(np.int64)
        height = part = None
        if near is not None and xyz is not None:
            mine = slice(offset, offset + rows.size)
            p = 1000.0 * xyz[rows, cols].astype(np.float64)
            q = 1000.0 * xyz[near[0][mine], near[1][mine]].astype(np.float64)
            ok = np.isfinite(p).all(axis=1)
            h = np.where(ok, q[:, 2] - p[:, 2], 0.0)  # the camera looks along +z: nearer it is higher
            d = np.where(ok, np.linalg.norm(p - q, axis=1), np.inf)
            n_ok = np.bincount(ids, weights=ok, minlength=n + 1)[1:]
            height = np.bincount(ids, weights=h, minlength=n + 1)[1:] / np.maximum(n_ok, 1)
            height[n_ok == 0] = np.nan
            part = np.full(n + 1, np.inf)
            np.minimum.at(part, ids, d)
            part = part[1:]
        offset += rows.size
        for k in range(n):
            fx = bk = 0
            consequence = None
            if truth is not None:
                fx, bk = int(fixes[k]), int(breaks[k])
                consequence = ("unscored" if fx + bk == 0 else "B fixes" if bk == 0 else "B breaks" if fx == 0
                               else "mixed")
            blobs.append(Blob(log, index, stamp_ns, who, int(area[k]),
                              None if mm2 is None else round(float(mm2[k]), 3), float(r[k]), float(c[k]), fx, bk,
                              consequence,
                              None if height is None or not np.isfinite(height[k]) else round(float(height[k]), 3),
                              None if part is None or not np.isfinite(part[k]) else round(float(part[k]), 3)))
    blobs.sort(key=lambda b: -b.area_px)
    return blobs


def scored_union(sa: SideFrame, sb: SideFrame) -> np.ndarray:
    """(H, W) bool: the union of the two sides' scored regions, where the comparison looks (the region
    itself, not a copy, when both sides have the same one: treat it as read-only)."""
    if sa.region is sb.region:
        return sa.region
    out: np.ndarray = sa.region | sb.region
    return out


def _score_frame(log: str, frame: Frame, sa: SideFrame, sb: SideFrame, pa: str, pb: str, truth_src: Any,
                 intrinsics: Any, *, depth_log: Path | None = None, where: np.ndarray | None = None,
                 ) -> tuple[FrameCompare, Any]:
    """One frame's comparison and its truth (``(outliers, scored)``, None without; its images:
    :func:`studies.compare_outputs.frame_images_bytes`).
    ``depth_log``: the log, when it has ``/ground_truth/depth``: the true outliers' displacement
    classes of each side's primary method, as ``zcut accuracy --by-displacement`` counts them.
    ``where``: :func:`scored_union` of the two sides, when the caller has it."""
    from annotate.accuracy import frame_accuracies, frame_displacement

    if where is None:
        where = scored_union(sa, sb)
    ma, mb = sa.preds[pa], sb.preds[pb]
    in_a, in_b = ma & where, mb & where
    n_a, n_b = int(np.count_nonzero(in_a)), int(np.count_nonzero(in_b))
    in_a &= in_b
    both = int(np.count_nonzero(in_a))
    only_a, only_b = n_a - both, n_b - both
    counts_a = counts_b = None
    unscored = None
    truth = None
    classes = None
    if truth_src is not None:
        t = truth_src.truth(frame, sa.valid)
        if isinstance(t, str):
            unscored = t
        else:
            shift = frame_displacement(depth_log, frame) if depth_log is not None else None  # read where scored
            # both sides in one pass: the truth prepared once when they share the zone (as two
            # frame_accuracy calls count them; tests/studies/test_compare_accuracy.py)
            fa, fb = frame_accuracies(frame.index, frame.stamp_ns, ((sa.preds, sa.valid, sa.region),
                                                                     (sb.preds, sb.valid, sb.region)),
                                      t.outliers, reviewed=t.reviewed, kinds=t.kind, displacement_mm=shift)
            counts_a, counts_b = fa.counts, fb.counts
            truth = (t.outliers, t.reviewed & where)
            if shift is not None:
                classes = {side: {fam: {"n": list(k.n), "found": list(k.found)} for fam, k in fx.classes[m].items()
                                  if fam == "by_displacement"}
                           for side, fx, m in (("a", fa, pa), ("b", fb, pb))}
    blobs = disagreement_blobs(log, frame.index, frame.stamp_ns, ma, mb, where, truth=truth, intrinsics=intrinsics,
                               xyz=frame.xyz)
    return (FrameCompare(log, frame.index, frame.stamp_ns, counts_a, counts_b, both, only_a, only_b, tuple(blobs),
                         unscored, classes), truth)


# ------------------------------------------------------------------------------------ the verdict
def side_counts(frames: list[FrameCompare], side: str, method: str) -> Counts:
    """Per-frame (TP, FP, FN) of one side's method over scored frames (``side``: "a" or "b")."""
    rows = []
    for f in frames:
        counts = f.a if side == "a" else f.b
        assert counts is not None
        c = counts[method]
        rows.append((c.tp, c.fp, c.fn))
    arr = np.array(rows, dtype=np.int64).reshape(len(rows), 3).T
    return arr[0], arr[1], arr[2]


def _fmt_signed(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:+.3f}"


def verdict(frames: list[FrameCompare], pa: str, pb: str, *, level: float = 0.95) -> dict[str, Any]:
    """Pooled figures of A's and B's primary methods, paired Δ with intervals, wins/losses/ties by
    per-frame F1 with the sign test, the frames where B loses (worst first), the one-line verdict."""
    from zcut.paired import FIGURES, frame_outcomes, paired_differences, sign_test

    scored = [f for f in frames if f.scored]
    if not scored:
        return {"figure": "f1", "truth": False,
                "line": "no truth: agreement only (A vs B: α, β, Jaccard of the removed pixels)"}
    a, b = side_counts(scored, "a", pa), side_counts(scored, "b", pb)
    diffs = paired_differences(a, b, level=level)
    outcome = frame_outcomes(a, b, figure="f1")
    wins, losses = int((outcome > 0).sum()), int((outcome < 0).sum())
    ties = len(scored) - wins - losses
    p = sign_test(wins, losses)
    d = diffs["f1"]
    ci = f"[{_fmt_signed(d.lo)}, {_fmt_signed(d.hi)}]" if d.has_interval else "[no interval: too few frames]"
    if d.has_interval and d.lo > 0:
        better = "B better"
    elif d.has_interval and d.hi < 0:
        better = "B worse"
    else:
        better = "no clear difference"
    line = (f"B: F1 {_fmt_signed(d.delta)} {ci}, {wins} wins / {losses} losses / {ties} ties of {len(scored)} "
            f"frames (sign test p = {p:.3g}): {better}")
    f1_frame = []
    for f in scored:
        assert f.a is not None and f.b is not None
        f1_frame.append((count_f1(f.b[pb]) - count_f1(f.a[pa]), f))
    losing = sorted([(dv, f) for (dv, f), o in zip(f1_frame, outcome) if o < 0], key=lambda x: x[0])
    return {
        "figure": "f1", "truth": True, "level": level, "line": line, "conclusion": better,
        "differences": {k: {"a": diffs[k].a, "b": diffs[k].b, "delta": diffs[k].delta,
                            "ci": [diffs[k].lo, diffs[k].hi]} for k in FIGURES},
        "wins": wins, "losses": losses, "ties": ties, "frames": len(scored), "sign_test_p": p,
        "losing_frames": [{"log": f.log, "index": f.index, "stamp_ns": f.stamp_ns, "delta_f1": dv}
                          for dv, f in losing],
    }


def per_method(frames: list[FrameCompare], level: float) -> dict[str, Any]:
    """Paired Δ of every method both sides report, on the scored frames."""
    from zcut.paired import FIGURES, paired_differences

    scored = [f for f in frames if f.scored]
    if not scored:
        return {}
    assert scored[0].a is not None and scored[0].b is not None
    common = [m for m in scored[0].a if m in scored[0].b]
    out = {}
    for m in common:
        a, b = side_counts(scored, "a", m), side_counts(scored, "b", m)
        d = paired_differences(a, b, level=level)
        out[m] = {k: {"a": d[k].a, "b": d[k].b, "delta": d[k].delta, "ci": [d[k].lo, d[k].hi]} for k in FIGURES}
    return out


def per_class(frames: list[FrameCompare], pa: str, pb: str, level: float,
              part_kinds: list[str] | None = None) -> dict[str, Any]:
    """The primary methods' paired differences per class of the truth (docs/compare.md): clusters and
    singletons (component counts of docs/accuracy.md: recall = true components found, precision =
    predicted components correct); where the truth says what each outlier is, recall per outlier
    kind (pixels); where the log has the true depth, recall per displacement class
    (:data:`annotate.accuracy.DISPLACEMENT_CLASSES`, pixels, over the frames that have them); and per
    part kind of the logs (``part_kinds``: each frame's log's, parallel to ``frames``) precision,
    recall and F1 over the frames of that kind's logs. Each entry: A's and B's pooled figure, B − A,
    and the paired interval over frames."""
    from annotate.accuracy import DISPLACEMENT_CLASSES
    from replay.logs.layout import OUTLIER_KINDS
    from zcut.paired import FIGURES, paired_differences

    kinds_of = part_kinds if part_kinds is not None else ["unknown"] * len(frames)
    scored = [f for f in frames if f.scored]
    if not scored:
        return {}
    ca = [f.a[pa] for f in scored if f.a is not None]
    cb = [f.b[pb] for f in scored if f.b is not None]

    def entry(fig: str, make: Any, xa: list[Any] = ca, xb: list[Any] = cb) -> dict[str, Any] | None:
        a = tuple(np.array(x, dtype=np.int64).reshape(len(xa)) for x in zip(*(make(c) for c in xa), strict=True))
        b = tuple(np.array(x, dtype=np.int64).reshape(len(xb)) for x in zip(*(make(c) for c in xb), strict=True))
        d = paired_differences(a, b, level=level)[fig]  # type: ignore[arg-type]
        if not (math.isfinite(d.a) or math.isfinite(d.b)):
            return None  # the class is empty
        return {"a": d.a, "b": d.b, "delta": d.delta, "ci": [d.lo, d.hi]}

    out: dict[str, Any] = {}
    for name, true_n, found, pred_n, correct in (
            ("clusters", "true_clusters", "true_clusters_found", "pred_clusters", "pred_clusters_correct"),
            ("singletons", "true_singletons", "true_singletons_found", "pred_singletons", "pred_singletons_correct")):
        row = {"recall": entry("recall", lambda c, t=true_n, f=found: (getattr(c, f), 0, getattr(c, t) - getattr(c, f))),
               "precision": entry("precision", lambda c, p=pred_n, k=correct: (getattr(c, k),
                                                                             getattr(c, p) - getattr(c, k), 0))}
        out[name] = {k: v for k, v in row.items() if v is not None}
    if all(c.kinds is not None for c in ca + cb) and ca:
        first = ca[0].kinds
        assert first is not None
        for code in range(1, len(first.n) + 1):
            def kind(c: Any, i: int = code - 1) -> tuple[int, int, int]:
                return c.kinds.found[i], 0, c.kinds.n[i] - c.kinds.found[i]

            e = entry("recall", kind)
            if e is not None:
                out[f"kind {OUTLIER_KINDS.get(code, code)}"] = {"recall": e}
    # the displacement classes |Z - Z_GT| of the true outliers, on the frames whose log has the true depth
    moved = [f.classes for f in scored if f.classes is not None and "by_displacement" in f.classes.get("a", {})
             and "by_displacement" in f.classes.get("b", {})]
    if moved:
        for i, name in enumerate(DISPLACEMENT_CLASSES):
            da = [c["a"]["by_displacement"] for c in moved]
            db = [c["b"]["by_displacement"] for c in moved]
            e = entry("recall", lambda k, i=i: (k["found"][i], 0, k["n"][i] - k["found"][i]), da, db)
            if e is not None:
                out[f"displacement {name}"] = {"recall": e}
    # the part kind of the logs: every figure over the frames of that kind's logs (always, one kind too)
    by_part: dict[str, list[FrameCompare]] = {}
    for f, k in zip(frames, kinds_of, strict=True):
        if f.scored:
            by_part.setdefault(k, []).append(f)
    for k in sorted(by_part):
        xa = [f.a[pa] for f in by_part[k] if f.a is not None]
        xb = [f.b[pb] for f in by_part[k] if f.b is not None]
        row = {fig: entry(fig, lambda c: (c.tp, c.fp, c.fn), xa, xb) for fig in FIGURES}
        out[f"part {k}"] = {fig: e for fig, e in row.items() if e is not None}
    return {k: v for k, v in out.items() if v}


def agreement(frames: list[FrameCompare]) -> dict[str, Any]:
    """α, β and the Jaccard index of the primary masks of A and B, pooled over every frame (A is method
    1, B method 2 of the paper's eqs. 3-4)."""
    from zcut.metrics import RelativeMetrics, ratio

    both = sum(f.both for f in frames)
    oa = sum(f.only_a for f in frames)
    ob = sum(f.only_b for f in frames)
    m = RelativeMetrics.from_counts(both, oa, ob)
    return {"both": both, "only_a": oa, "only_b": ob, "alpha": m.alpha, "beta_a": m.beta1, "beta_b": m.beta2,
            "jaccard": ratio(both, both + oa + ob)}


def _pooled(frames: list[FrameCompare], side: str) -> dict[str, Any]:
    """Every reported method's pooled entry of one side, as ``zcut accuracy --json`` writes it."""
    from annotate.accuracy import FrameAccuracy, accuracy_report

    scored = [f for f in frames if f.scored]
    if not scored:
        return {}
    fas = [FrameAccuracy(i, f.stamp_ns, getattr(f, side.lower())) for i, f in enumerate(scored)]
    pooled: dict[str, Any] = accuracy_report(fas, region="valid")["pooled"]
    return pooled


# ------------------------------------------------------------------------------------ outputs
def _entry_of(c: Any) -> dict[str, Any]:
    d = c.as_dict()
    return {k: (int(v) if k in ("tp", "fp", "fn") else v) for k, v in d.items()}


def run(opts: CompareOptions) -> CompareResult:
    """Compare ``opts.a`` and ``opts.b`` on ``opts.logs``; write the outputs into ``opts.out``.

    The frames run in units on the executor the options choose (``workers``, ``ray``), each unit's
    frames kept in ``opts.out/parts`` as it finishes; a rerun over the same folder runs only the units
    not done. Says on stderr what runs and how far it is.

    Raises
    ------
    CompareError, ConfigError, OutputError, LogFormatError
        Bad input, one line each; nothing is written then.
    """
    from contextlib import ExitStack

    from annotate.truth import check_region, check_truth

    t_wall, t_cpu = time.perf_counter(), time.process_time()
    check_region(opts.region)
    check_truth(opts.truth)
    if not opts.logs:
        raise CompareError("no log given")
    if isinstance(opts.frames_per_unit, bool) or opts.frames_per_unit < 1:
        raise ConfigError(f"--frames-per-unit must be >= 1, got {opts.frames_per_unit!r}")
    for p in (*opts.logs, *(x for x in (opts.labels, opts.bin_model, opts.part_model) if x is not None)):
        if not Path(p).is_file():
            raise FileNotFoundError(2, "no such file", str(p))
    if opts.truth is not None and opts.labels is not None:
        raise CompareError(f"--truth {opts.truth} scores against the log's recorded truth, --labels against "
                           "an annotator's: give one")
    if opts.part_model is not None:  # a bad mesh is one line before anything runs
        from replay.pipeline.explained import part_model

        part_model(str(opts.part_model), opts.part_model_unit)
    spec_a, spec_b = side_spec(opts.a, label="A"), side_spec(opts.b, label="B")
    out = Path(opts.out)
    if out.exists() and not out.is_dir():
        raise CompareError(f"-o {out}: exists and is not a folder")
    with ExitStack() as stack:
        return _run(opts, spec_a, spec_b, stack, t_wall, t_cpu)


def _limited(units: list[WorkUnit], frames: tuple[int, int | None]) -> list[WorkUnit]:
    """The units cut to the frame range ``frames`` (those outside it dropped)."""
    from dataclasses import replace

    lo, hi = frames
    out = []
    for u in units:
        start = max(u.start, lo)
        ends = [x for x in (u.stop, hi, None if u.n_frames is None else u.start + u.n_frames) if x is not None]
        end = min(ends) if ends else None
        if end is not None and end <= start:
            continue
        stop = u.stop if hi is None or (u.stop is not None and u.stop <= hi) else hi
        out.append(replace(u, start=start, stop=stop, n_frames=None if end is None else end - start))
    return out


def _identity(opts: CompareOptions, spec_a: SideSpec, spec_b: SideSpec, plans: list[LogPlan],
              sides: dict[str, LogSides]) -> dict[str, Any]:
    """What identifies a comparison in its folder (``run.json``, :class:`studies.parts.PartStore`): the
    sides, the options, the logs in order (another log set is another comparison) and per log the
    content hashes of A's and B's resolved configs."""
    from replay.pipeline.config import config_sha256
    from studies.driver import absolute, file_identity

    def side(spec: SideSpec) -> dict[str, Any]:
        return {"kind": spec.kind, "spec": spec.text if spec.path is None else None,
                "sha256": file_identity(str(spec.path)) if spec.path is not None else None}

    options = {"a": side(spec_a), "b": side(spec_b), "labels": absolute(None if opts.labels is None else str(opts.labels)),
               "annotator": opts.annotator, "region": opts.region, "truth": opts.truth,
               "bin_model_sha256": file_identity(None if opts.bin_model is None else str(opts.bin_model)),
               "part_model_sha256": file_identity(None if opts.part_model is None else str(opts.part_model)),
               "part_model_unit": opts.part_model_unit, "topic": opts.topic, "frames": list(opts.frames),
               "frames_per_unit": opts.frames_per_unit, "logs": [p.sha256 for p in plans if p.units]}
    logs = {sha: [None if c is None else config_sha256(c) for c in (s.configs["A"], s.configs["B"])]
            for sha, s in sides.items()}
    return {"kind": "compare", "options": options, "logs": logs,
            "paths": {str(p.path): p.sha256 for p in plans if p.sha256}}


def _absolute(opts: CompareOptions, *specs: SideSpec) -> tuple[CompareOptions, list[SideSpec]]:
    """The options and sides with absolute paths (the units may run in another folder, on another node)."""
    from dataclasses import replace

    def ab(p: Path | None) -> Path | None:
        return None if p is None else Path(os.path.abspath(p))

    o = replace(opts, logs=tuple(Path(os.path.abspath(p)) for p in opts.logs), out=Path(os.path.abspath(opts.out)),
                labels=ab(opts.labels), bin_model=ab(opts.bin_model), part_model=ab(opts.part_model))
    return o, [replace(s, path=ab(s.path)) for s in specs]


def _run(opts: CompareOptions, spec_a: SideSpec, spec_b: SideSpec, stack: ExitStack, t_wall: float,
         t_cpu: float) -> CompareResult:
    import sys

    from annotate.disagreement import FILE as DISAGREEMENT
    from replay.outputs import OutputPlan, naming
    from studies.driver import Progress, check_labels, meta_of, plan_logs, start_units
    from studies.executors import make_executor
    from studies.parts import PARTS, PartStore
    from studies.work import Job

    # the executor is made once every input is checked (a Ray cluster is connected to then, local workers
    # start when the units run): bad input is one line before anything starts
    executor: Executor | None = None
    try:
        def planning(i: int, n: int, path: Path) -> None:
            if n > 5 and (i % 20 == 0 or i == n - 1):
                print(f"zcut: reading {n} logs: {i + 1}/{n} {path.name}", file=sys.stderr, flush=True)

        # each log opened once: the planning's reader resolves the sides (their errors raised after the
        # planning, as before); in this process (--workers 0) the units of the first _MAX_KEPT // 2 logs take
        # it too (half the kept entries: each log's runner, kept beside its reader, must not push out the
        # reader of a log whose units are still to come)
        sides: dict[str, LogSides] = {}
        refused: list[Exception] = []
        inline = opts.workers == 0 and opts.ray is None  # make_executor's InlineExecutor

        from annotate.truth import truth_of_log
        from replay.logs.identity import log_identity
        from replay.logs.reader import LogReader

        given = {Path(p).resolve(): p for p in opts.logs}  # a log named in an error as it was given

        def opened(plan: LogPlan, reader: Any, first: Frame) -> None:
            if refused:
                return
            if opts.truth is not None:  # the truth asked for is in every log, before anything is written
                try:
                    truth_of_log(opts.truth, reader.mask_topics, given.get(plan.path, plan.path))
                except Exception as e:  # noqa: BLE001 - raised after the planning
                    refused.append(e)
                    return
            if not plan.units:
                return
            try:
                sides[plan.sha256] = resolve_log(opts, spec_a, spec_b, plan.path, reader, first)
            except Exception as e:  # noqa: BLE001 - raised after the planning, as when the sides were resolved then
                refused.append(e)
                return
            if inline and sum(k[0] == "log" for k in _KEPT) < _MAX_KEPT // 2:
                _kept(("log", str(plan.path), plan.sha256, opts.topic), lambda: (reader, first))

        plans = plan_logs([str(p) for p in opts.logs], config_file=None, overrides={}, topic=opts.topic,
                          frames_per_unit=opts.frames_per_unit, whole=False, progress=planning,
                          bin_model=None if opts.bin_model is None else str(opts.bin_model), opened=opened,
                          reader_options=READER_OPTIONS, identify=log_identity)
        check_labels(None if opts.labels is None else str(opts.labels), opts.annotator, plans, labelled=True)
        if refused:
            raise refused[0]
        if opts.truth is not None:  # a log the planning could not open: checked as it is given
            for plan in plans:
                if plan.error is not None:
                    p = given.get(plan.path, plan.path)
                    truth_of_log(opts.truth, LogReader(p, cloud_topic=opts.topic).mask_topics, p)
        for plan in plans:
            if plan.units:
                plan.units = _limited(plan.units, opts.frames)
        usable = {p.sha256 for p in plans if p.units}
        sides = {sha: s for sha, s in sides.items() if sha in usable}
        primaries = next(sides[p.sha256].primaries for p in plans if p.sha256 in sides)
        executor = make_executor(workers=opts.workers, ray=opts.ray)  # an unreachable cluster fails here
        out = Path(opts.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        store = stack.enter_context(PartStore(out, _identity(opts, spec_a, spec_b, plans, sides),
                                              start_afresh=opts.force))
        inputs: list[str | os.PathLike[str]] = [
            *(p.path for p in plans), *(s.path for s in (spec_a, spec_b) if s.path is not None),
            *(x for x in (opts.labels, opts.bin_model, opts.part_model) if x is not None)]
        names = {"json": "compare.json", "parquet": "summary.parquet", "disagreement": DISAGREEMENT}
        if opts.report:
            names["report"] = "report.html"
        if opts.rrd:
            names["rrd"] = "compare.rrd"
        plan_out = stack.enter_context(OutputPlan(inputs, force=opts.force))
        paths = {k: plan_out.add(out / v, f"the comparison's {v}") for k, v in names.items()}
        units, todo = start_units(plans, store, what="", executor=executor)
        abs_opts, (abs_a, abs_b) = _absolute(opts, spec_a, spec_b)
        job = Job(config_file=None, overrides={}, bin_model=None if abs_opts.bin_model is None else str(abs_opts.bin_model),
                  topic=opts.topic, labels=None if abs_opts.labels is None else str(abs_opts.labels),
                  annotator=opts.annotator, region=opts.region, configs=dict(sides), truth=opts.truth,
                  extra={"options": abs_opts, "a": abs_a, "b": abs_b, "primaries": primaries})
        progress = Progress(sum(u.n_frames or 0 for u in todo) or None)
        writer = _Assembler(opts, spec_a, spec_b, plans, sides, primaries, store, paths)
        stack.callback(writer.abort)  # an error or an interruption: no output is named
        writer.advance({})  # the units done in an earlier run over DIR, up to the first not done
        results: list[UnitResult] = []
        failed: dict[str, str] = {}
        try:
            # as driver.execute, the writer taking each frame as soon as the units before it are done
            for unit, res in executor.run(run_compare_unit, todo, job):
                results.append(res)
                if res.error is None:
                    with naming(store.root / PARTS):  # a full disk met by a unit's part (Arrow's error names no file)
                        store.write(unit.key, res.rows, meta_of(res), schema=part_schema())
                else:
                    failed[unit.key] = res.error
                note = f"{Path(unit.log).name} failed: {res.error.splitlines()[0][:60]}" if res.error else ""
                progress.update(res.frames, note=note, force=bool(note))
                writer.advance(failed)
        finally:
            executor.close()
        progress.finish()
    finally:
        if executor is not None:
            executor.close()
        _KEPT.clear()  # what the units kept when they ran in this process (--workers 0)
    assert executor is not None
    return writer.finish(results, executor, t_wall, t_cpu)


# ------------------------------------------------------------------------------------ one unit
def run_compare_unit(unit: WorkUnit, job: Job) -> UnitResult:
    """Compare A and B on the frames of one unit (in a worker): one row per frame
    (:data:`studies.compare_records.PART_COLUMNS`). Any error of the unit (a damaged log, a bug) is
    caught into the result's ``error``, never raised: one bad unit does not stop the others."""
    from replay.logs import layout
    from studies.compare_outputs import frame_images_bytes
    from studies.work import caught_unit

    def body(res: UnitResult, held: list[Any]) -> None:
        opts: CompareOptions = job.extra["options"]
        spec_a: SideSpec = job.extra["a"]
        spec_b: SideSpec = job.extra["b"]
        pa, pb = job.extra["primaries"]
        sides: LogSides | None = job.configs.get(unit.sha256)
        path = Path(unit.log)
        if sides is None:
            raise CompareError(f"{path.name}: the driver resolved no sides for this log")
        reader, first = _open_unit_log(path, unit.sha256, opts.topic)
        truth_src = _truth_source(opts, path, tuple(reader.mask_topics))
        held.append(truth_src)
        truth_name = truth_src.name if truth_src is not None else None
        depth_log = path if layout.TRUTH_DEPTH in reader.topics else None  # the displacement classes
        runs: Counter[str] = Counter()
        lost: list[Any] = []
        it = _frames_of_log(opts, spec_a, spec_b, path, sides, reader, first, (unit.start, unit.stop), runs, lost,
                            unit.sha256)
        try:
            seen: Counter[str] = Counter()
            for frame, sa, sb in it:
                row: dict[str, Any] = {"log": path.name, "log_sha256": unit.sha256, "frame": frame.index,
                                       "stamp_ns": frame.stamp_ns, "record": None, "skipped": None,
                                       "truth": truth_name, "stage_runs": json.dumps(dict(runs - seen)),
                                       "images": None}
                seen = Counter(runs)
                res.rows.append(row)
                if sa is None or sb is None:
                    row["skipped"] = (f"frame {frame.index} (stamp {frame.stamp_ns}): not in the results file "
                                      f"{(spec_a if sa is None else spec_b).path}: skipped")
                    continue
                if pa not in sa.preds or pb not in sb.preds:
                    raise CompareError(f"{path.name}: the primary methods {pa} (A) and {pb} (B) must be the same "
                                       "on every log")
                where = scored_union(sa, sb)
                fc, truth = _score_frame(path.name, frame, sa, sb, pa, pb, truth_src, first.intrinsics,
                                         depth_log=depth_log, where=where)
                row["record"] = frame_to_json(fc)
                row["images"] = frame_images_bytes(sa, sb, truth, pa, pb, frame if opts.rrd else None, where=where)
                if fc.unscored is not None:
                    res.unscored.append({"index": frame.index, "stamp_ns": frame.stamp_ns, "reason": fc.unscored})
                res.frames += 1
                del frame, sa, sb, where, fc, truth  # freed before the next frame (PairRunner._frames)
        finally:
            it.close()
            res.damage = list(lost)

    res = caught_unit(unit, body)
    if res.error is not None:
        res.rows = []
    return res


# ------------------------------------------------------------------------------------ the one writer
def _part_rows(store: PartStore, key: str) -> list[dict[str, Any]]:
    import pyarrow.parquet as pq

    from studies.parts import PARTS

    rows: list[dict[str, Any]] = pq.read_table(store.root / PARTS / f"{key}.parquet").to_pylist()
    return sorted(rows, key=lambda r: r["frame"])


def _part_meta(store: PartStore, key: str) -> dict[str, Any]:
    """A finished unit's meta (``parts/KEY.json``; empty when it does not read)."""
    from studies.parts import PARTS

    try:
        meta: dict[str, Any] = json.loads((store.root / PARTS / f"{key}.json").read_text())
    except (OSError, ValueError):
        return {}
    return meta


class _Reread:
    """A unit's frames read again from its log (``reader``), in order: the recording's content of the
    frames whose part holds none (a part written by a comparison without ``compare.rrd``)."""

    def __init__(self, reader: Any, unit: WorkUnit) -> None:
        self.stream = reader.frames(start=unit.start, stop=unit.stop)
        self.last: Any = None

    def get(self, index: int) -> Any:
        while self.last is None or self.last.index < index:
            nxt = next(self.stream, None)
            if nxt is None:
                return None
            self.last = nxt
        return self.last if self.last.index == index else None

    def close(self) -> None:
        self.stream.close()


class _Assembler:
    """The one writer: every unit's frames in log order and frame order (those done in an earlier run
    too) into the recording and the disagreement as soon as the units before them are done
    (:meth:`advance`, after each unit), then the tables and the page (:meth:`finish`)."""

    def __init__(self, opts: CompareOptions, spec_a: SideSpec, spec_b: SideSpec, plans: list[LogPlan],
                 sides: dict[str, LogSides], primaries: tuple[str, str], store: PartStore,
                 paths: dict[str, Path]) -> None:
        from studies.compare_outputs import CompareWriter

        self.opts, self.spec_a, self.spec_b, self.plans = opts, spec_a, spec_b, plans
        self.sides, self.primaries, self.store, self.paths = sides, primaries, store, paths
        self.frames: list[FrameCompare] = []
        self.kinds: list[str] = []  # each frame's log's part kind
        self.logs: list[_Log] = []
        self.runs: Counter[str] = Counter()
        self.truth_names: set[str] = set()
        self.given = {Path(os.path.abspath(p)): Path(p) for p in opts.logs}  # a log named as given (a folder's: its path)
        self.given.update({Path(p).resolve(): Path(p) for p in opts.logs})
        self.writer = CompareWriter(paths, has_truth=None)
        self.started = False
        #: what is left to write, in order: ("log", plan) starts a log, ("unit", plan, unit) its unit
        self.steps: list[tuple[Any, ...]] = []
        for plan in plans:
            self.steps.append(("log", plan))
            if plan.error is None and plan.sha256 in sides:
                self.steps += [("unit", plan, u) for u in plan.units]
        self.at = 0
        self.closed = False
        self.reader: Any = None  # the current log's reader, opened only to read a frame again

    def advance(self, failed: dict[str, str], *, last: bool = False) -> None:
        """Write every frame whose unit and every unit before it are done (or failed: ``failed``, unit key
        -> error); ``last``: every unit left, a unit not done being named in its log's damage."""
        while self.at < len(self.steps):
            step = self.steps[self.at]
            if step[0] == "log":
                self._log(step[1])
            else:
                u = step[2]
                done = u.key not in failed and self.store.done(u.key)
                if not (done or last or u.key in failed):
                    return
                entry = self.logs[-1]
                if not done:
                    entry.damage.append(f"frames {u.start}-{u.stop if u.stop is not None else 'end'} not compared: "
                                        f"{failed.get(u.key) or 'the unit did not finish'}")
                else:
                    self._unit(step[1], u, entry)
            self.at += 1

    def _log(self, plan: LogPlan) -> None:
        entry = _Log(self.given.get(plan.path, plan.path))
        self.logs.append(entry)
        self.reader = None
        if plan.error is not None or plan.sha256 not in self.sides:
            entry.damage.append(f"left out: {plan.error or 'no frames'}")
            return
        s = self.sides[plan.sha256]
        entry.resolved_a, entry.resolved_b = s.configs["A"], s.configs["B"]
        entry.diff, entry.shared, entry.primaries, entry.part_kind = s.diff, s.shared, s.primaries, s.part_kind
        if s.resolved and plan.bin_model_warning:
            entry.notes.append(plan.bin_model_warning)
        self.writer.log(plan.path, sha256=plan.sha256)  # the planning's hash: the log is not read again for it

    def _unit(self, plan: LogPlan, u: WorkUnit, entry: _Log) -> None:
        from studies.compare_outputs import frame_view

        pa, pb = self.primaries
        reread: _Reread | None = None
        try:
            for row in _part_rows(self.store, u.key):
                self.runs.update(json.loads(row["stage_runs"] or "{}"))
                if row["truth"] is not None:
                    self.truth_names.add(row["truth"])
                if row["record"] is None:
                    entry.damage.append(row["skipped"])
                    continue
                fc = frame_from_json(row["record"])
                if not self.started:
                    self.writer.start(self.spec_a, self.spec_b, entry.diff, has_truth=row["truth"] is not None,
                                      primaries=self.primaries)
                    self.started = True
                images = FrameImages.from_bytes(row["images"])
                view = images.view
                if view is None and "rrd" in self.paths:  # a part without the recording's content: read it again
                    if reread is None:
                        if self.reader is None:
                            from replay.logs.reader import LogReader

                            self.reader = LogReader(plan.path, cloud_topic=self.opts.topic)
                        reread = _Reread(self.reader, u)
                    frame = reread.get(fc.index)
                    view = None if frame is None else frame_view(frame, images.diff)
                self.writer.frame(fc, images, pa, pb, view)
                entry.n_frames += 1
                entry.n_unscored += fc.unscored is not None
                self.frames.append(fc)
                self.kinds.append(entry.part_kind)
        finally:
            if reread is not None:
                reread.close()
        entry.damage += _part_meta(self.store, u.key).get("damage", [])

    def finish(self, results: list[UnitResult], executor: Executor, t_wall: float, t_cpu: float) -> CompareResult:
        """Every unit left (named in the damage when not done), then compare.json, the tables, the page;
        every output named."""
        failed = {r.unit.key: r.error for r in results if r.error is not None}
        self.advance(failed, last=True)
        if not self.started:
            raise CompareError("no readable frame in " + ", ".join(str(p) for p in self.opts.logs))
        pa, pb = self.primaries
        frames, plans, paths = self.frames, self.plans, self.paths
        report = _report(self.opts, self.spec_a, self.spec_b, self.logs, frames, self.kinds, pa, pb, self.runs,
                         self.truth_names)
        this_run = [r for r in results if r.error is None]
        n_now = sum(r.frames for r in this_run)
        cpu_units = sum(r.cpu_seconds for r in this_run)
        cpu = time.process_time() - t_cpu + (cpu_units if executor.workers else 0.0)
        report["cost"] = {"frames": len(frames), "wall_s": time.perf_counter() - t_wall, "cpu_s": cpu,
                          "frames_this_run": n_now,
                          "cpu_s_per_frame": cpu_units / n_now if n_now else None,
                          "executor": executor.name, "workers": executor.workers,
                          "units": sum(len(p.units) for p in plans), "units_this_run": len(results)}
        report["outputs"] = {k: str(v) for k, v in paths.items()}
        self.writer.finish(report, summary_rows(report, frames))  # an error: abort() (the caller's) names nothing
        self.writer.close(completed=True)
        self.closed = True
        return CompareResult(report, frames, {k: str(v) for k, v in paths.items()}, self.runs,
                             data_loss=any(e.damage for e in self.logs))

    def abort(self) -> None:
        """Nothing named (an error, an interruption); safe after :meth:`finish` (then nothing to do)."""
        if not self.closed:
            self.closed = True
            self.writer.close(completed=False)


def _report(opts: CompareOptions, spec_a: SideSpec, spec_b: SideSpec, logs: list[_Log], frames: list[FrameCompare],
            kinds: list[str], pa: str, pb: str, runs: Counter[str], truth_names: set[str]) -> dict[str, Any]:
    """The compare.json object (docs/compare.md documents every key)."""
    from annotate.accuracy import classes_entry
    from zcut.metrics import KindCounts
    from zcut.paired import frame_outcomes

    v = verdict(frames, pa, pb, level=opts.level)
    scored = [f for f in frames if f.scored]
    outcomes: dict[tuple[str, int], int] = {}
    if scored:
        a, b = side_counts(scored, "a", pa), side_counts(scored, "b", pb)
        outcomes = {(f.log, f.index): int(o) for f, o in zip(scored, frame_outcomes(a, b))}
    frames_json = []
    for f in frames:
        e: dict[str, Any] = {"log": f.log, "index": f.index, "stamp_ns": f.stamp_ns, "scored": f.scored,
                             "unscored": f.unscored, "both": f.both, "only_a": f.only_a, "only_b": f.only_b,
                             "blobs": len(f.blobs)}
        if f.scored:
            assert f.a is not None and f.b is not None
            e["a"] = {m: _entry_of(c) for m, c in f.a.items()}
            e["b"] = {m: _entry_of(c) for m, c in f.b.items()}
            e["delta_f1"] = count_f1(f.b[pb]) - count_f1(f.a[pa])
            e["outcome"] = outcomes[(f.log, f.index)]
            if f.classes is not None and "by_displacement" in f.classes.get("a", {}):
                e["by_displacement"] = {side: classes_entry("by_displacement", KindCounts(
                    tuple(k["n"]), tuple(k["n"]), tuple(k["found"])))
                    for side, k in ((s, f.classes[s]["by_displacement"]) for s in "ab")}
        frames_json.append(e)
    # worst regression first: the frames B loses most on (by ΔF1), else the most disagreement
    order = sorted(range(len(frames)), key=lambda i: (frames_json[i].get("delta_f1", 0.0),
                                                      -(frames[i].only_a + frames[i].only_b)))
    blobs = []
    n_blobs = 0
    for i in order:
        f = frames[i]
        n_blobs += len(f.blobs)
        blobs += [b.as_dict() for b in f.blobs[:MAX_BLOBS_PER_FRAME]]
    first = next((e for e in logs if e.n_frames), logs[0])
    return {
        "a": {**spec_a.as_dict(), "primary": pa,
              "methods": list(first.resolved_a.methods) if first.resolved_a is not None else None},
        "b": {**spec_b.as_dict(), "primary": pb,
              "methods": list(first.resolved_b.methods) if first.resolved_b is not None else None},
        "config_difference": first.diff,
        "truth": sorted(truth_names)[0] if len(truth_names) == 1 else (sorted(truth_names) or None),
        "region": opts.region,
        "logs": [{"log": str(e.path), "part_kind": e.part_kind, "frames": e.n_frames, "unscored": e.n_unscored,
                  "damage": e.damage,
                  "notes": e.notes, "config_difference": e.diff, "shared": e.shared} for e in logs],
        "shared": first.shared,
        "stage_runs": dict(sorted(runs.items())),
        "pooled": {"a": _pooled(frames, "A"), "b": _pooled(frames, "B")},
        "verdict": v,
        "per_method": per_method(frames, opts.level),
        "per_class": per_class(frames, pa, pb, opts.level, kinds),
        "agreement": agreement(frames),
        "frames": frames_json,
        "frames_worst_first": [{"log": frames[i].log, "index": frames[i].index,
                                "delta_f1": frames_json[i].get("delta_f1")} for i in order],
        "blobs": blobs,
        "blobs_total": n_blobs,
        "blob_fields": "connected components (8-connected) of the pixels only one side removed, frames worst "
                       f"regression first, at most {MAX_BLOBS_PER_FRAME} per frame (the largest)",
    }
