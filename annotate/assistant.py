"""The labelling assistant: a classifier that learns from the labels already given which review groups
are outliers, and proposes a label and a confidence for every group of the frames still to review.

- **Features.** Per review group (:mod:`annotate.groups`, :data:`annotate.groups.FEATURES`): size,
  gap to the local surface (mm and in units of the frame's residual threshold τ), height extent,
  surface residuals, the share of its pixels each suspect detector and each filter flags, the
  distance to the nearest unmeasured pixel (occlusion edges), the roughness of the surface around
  it, its brightness and contrast in the colour image, its box's fill and aspect, the frame's noise.
- **Targets.** A group is labelled when at least half of its pixels are reviewed; it is an outlier
  when at least half of them are labelled outliers. Every annotator's current labels are used; a
  group the annotators label differently is left out and counted (:attr:`TrainingSet.disagreements`).
- **Held-out accuracy.** Before the model that proposes is fitted on every labelled frame, models
  are fitted with whole frames held out (up to 5 folds) and scored on them: the accuracy on
  held-out frames, and that of the confident proposals alone, is what the page shows.
- **Proposals.** ``p`` = the probability that a group is an outlier; the proposal is ``p >= 0.5``,
  its confidence ``max(p, 1 - p)``; the page pre-fills the groups whose confidence is at least
  :data:`CONFIDENT` — only when the model's part kind is the log's (:meth:`Model.applies_to`), it
  was checked on held-out frames and it agrees with the labels on at least :data:`GATE` of the
  held-out groups (``zcut annotate --assistant-gate``). Below that its proposals are shown and
  nothing is pre-filled; ``zcut labels train`` warns.
- **Library.** LightGBM (``bench/bench_assistant.py`` measured it against scikit-learn's
  HistGradientBoosting and XGBoost on the same held-out frames; the README's dependency table has
  the figures). Its model is stored as LightGBM's own text format, never as a pickle.

Bad input is a :class:`TrainingError` with one line saying what to do: no labelled frame, one class
only. Nothing here touches the store's labels.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from annotate.groups import FEATURES
from zcut.errors import ZcutError

if TYPE_CHECKING:
    import lightgbm as lgb
    import xgboost as xgb
    from sklearn.ensemble import HistGradientBoostingClassifier

    from annotate.catalogue import Catalogue
    from annotate.payload import ServedFrame
    from annotate.store import LabelStore, LogRecord, ModelRecord
    from replay.logs.frame import Frame
    from replay.pipeline.config import PipelineConfig
    from replay.pipeline.session import ReplaySession
    from replay.pipeline.stages import FrameResult

#: Proposals at least this confident are pre-filled on the page (one input accepts them).
CONFIDENT = 0.9
#: The held-out agreement with the labels a model needs before the page pre-fills its proposals.
GATE = 0.9
#: Folds of whole frames held out to measure the model (fewer when fewer frames are labelled).
FOLDS = 5
BACKEND = "lightgbm"
# small trees regularised as XGBoost's defaults are (L2 1, a leaf needs a hessian of 1): without that the
# leaves of a few hundred groups become overconfident (bench_assistant.py: log loss 0.46 against 0.16)
_LGB_PARAMS = {"objective": "binary", "learning_rate": 0.1, "num_leaves": 7, "min_data_in_leaf": 3,
               "min_data_in_bin": 1, "lambda_l2": 1.0, "min_sum_hessian_in_leaf": 1.0, "feature_fraction": 0.9,
               "verbose": -1, "num_threads": 1, "seed": 7, "deterministic": True}
_ROUNDS = 120


class TrainingError(ZcutError, ValueError):
    """The labels cannot train a model (none, one class only); the message says what to label."""


@dataclass(frozen=True, slots=True)
class TrainingSet:
    """Labelled groups of labelled frames.

    Attributes
    ----------
    X : (n, len(FEATURES)) float32 ndarray
    y : (n,) bool ndarray
        The group is an outlier.
    frame : (n,) int64 ndarray
        Which labelled frame each group comes from (an index into ``frames``).
    frames : tuple of (str, int)
        (topic, stamp_ns) of each labelled frame.
    annotators : tuple of str
    disagreements : int
        Groups left out because annotators labelled them differently.
    """

    X: np.ndarray
    y: np.ndarray
    frame: np.ndarray
    frames: tuple[tuple[str, int], ...]
    annotators: tuple[str, ...]
    disagreements: int = 0


class TrainingSetBuilder:
    """Collects labelled groups frame by frame (:meth:`add`), then :meth:`build`."""

    def __init__(self) -> None:
        self._X: list[np.ndarray] = []
        self._y: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self.frames: list[tuple[str, int]] = []
        self.annotators: set[str] = set()
        self.disagreements = 0

    def add(self, key: tuple[str, int], features: np.ndarray, labels: Sequence[tuple[str, np.ndarray, np.ndarray]]
            ) -> None:
        """One frame: its groups' features and, per annotator, (name, decided, outlier share) per group."""
        if not labels or features.shape[0] == 0:
            return
        n = features.shape[0]
        votes = np.zeros(n)
        count = np.zeros(n)
        for who, decided, share in labels:
            votes += decided & (share >= 0.5)
            count += decided
            if decided.any():
                self.annotators.add(who)
        keep = count > 0
        agree = keep & ((votes == 0) | (votes == count))
        self.disagreements += int((keep & ~agree).sum())
        if not agree.any():
            return
        self._X.append(features[agree])
        self._y.append(votes[agree] > 0)
        self._f.append(np.full(int(agree.sum()), len(self.frames), np.int64))
        self.frames.append(key)

    def build(self) -> TrainingSet:
        if not self._X:
            return TrainingSet(np.zeros((0, len(FEATURES)), np.float32), np.zeros(0, bool), np.zeros(0, np.int64),
                               (), tuple(sorted(self.annotators)), self.disagreements)
        return TrainingSet(np.concatenate(self._X).astype(np.float32), np.concatenate(self._y),
                           np.concatenate(self._f), tuple(self.frames), tuple(sorted(self.annotators)),
                           self.disagreements)


# --------------------------------------------------------------------------- backends
class Predictor(Protocol):
    """What scores groups: ``predict(X) -> p``, the outlier probability of each row of features."""

    def predict(self, X: np.ndarray) -> np.ndarray: ...


class Booster(Predictor, Protocol):
    """A fitted classifier of a backend, which a store keeps as bytes."""

    def dumps(self) -> bytes: ...


def fit_booster(X: np.ndarray, y: np.ndarray, *, backend: str = BACKEND) -> Booster:
    """A fitted classifier of ``backend`` (``lightgbm``, ``xgboost``, ``hgb``) with ``predict(X) -> p``."""
    if backend == "lightgbm":
        import lightgbm as lgb

        return _Lgb(lgb.train(_LGB_PARAMS, lgb.Dataset(X, y.astype(np.float64), free_raw_data=True),
                              num_boost_round=_ROUNDS))
    if backend == "xgboost":
        import xgboost as xgb

        d = xgb.DMatrix(X, label=y.astype(np.float64))
        return _Xgb(xgb.train({"objective": "binary:logistic", "eta": 0.1, "max_depth": 4, "nthread": 1,
                               "seed": 7}, d, num_boost_round=_ROUNDS))
    if backend == "hgb":
        from sklearn.ensemble import HistGradientBoostingClassifier

        return _Hgb(HistGradientBoostingClassifier(max_iter=_ROUNDS, learning_rate=0.1, max_leaf_nodes=15,
                                                   min_samples_leaf=3, random_state=7).fit(X, y))
    raise ValueError(f"unknown backend {backend!r}")


@dataclass
class _Lgb:
    booster: lgb.Booster

    def predict(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(self.booster.predict(np.asarray(X, np.float32), num_threads=1), np.float64)

    def dumps(self) -> bytes:
        return self.booster.model_to_string().encode()


@dataclass
class _Xgb:
    booster: xgb.Booster

    def predict(self, X: np.ndarray) -> np.ndarray:
        import xgboost as xgb

        return np.asarray(self.booster.predict(xgb.DMatrix(np.asarray(X, np.float32))), np.float64)

    def dumps(self) -> bytes:
        return bytes(self.booster.save_raw("json"))


@dataclass
class _Hgb:
    clf: HistGradientBoostingClassifier

    def predict(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(self.clf.predict_proba(np.asarray(X, np.float32))[:, 1], np.float64)

    def dumps(self) -> bytes:
        raise TrainingError("scikit-learn's models are stored only as pickles: zcut does not store them")


def _single_class(y: np.ndarray) -> Predictor:
    """A constant 'model' for a fold whose training frames hold one class only."""
    v = float(y[0]) if y.size else 0.5

    class _Const:
        def predict(self, X: np.ndarray) -> np.ndarray:
            return np.full(len(X), v)

    return _Const()


# --------------------------------------------------------------------------- the model
@dataclass(frozen=True)
class HeldOut:
    """How the model did on labelled frames it was not trained on.

    Attributes
    ----------
    frames, groups : int
        Held-out frames and their labelled groups.
    accuracy : float
        Share of held-out groups whose proposal matched the label (NaN without held-out frames).
    confident, confident_accuracy : int, float
        Held-out groups proposed with confidence >= :data:`CONFIDENT`, and their accuracy.
    """

    frames: int
    groups: int
    accuracy: float
    confident: int
    confident_accuracy: float

    def as_dict(self) -> dict[str, int | float | None]:
        def f(v: float) -> float | None:
            return None if not np.isfinite(v) else round(float(v), 4)

        return {"frames": self.frames, "groups": self.groups, "accuracy": f(self.accuracy),
                "confident": self.confident, "confident_accuracy": f(self.confident_accuracy)}


@dataclass
class Model:
    """A trained assistant: proposals for groups, its held-out figures and what it was trained on.

    Attributes
    ----------
    booster : object
        ``predict(X) -> p`` (outlier probability).
    part : str or None
        The part kind of the labelled log (None: unknown).
    held_out : HeldOut
    frames : tuple of (str, int)
        (topic, stamp_ns) of the frames it was trained on: ``zcut accuracy`` scores it only on others.
    log_sha256 : str
    annotators : tuple of str
    n_groups, n_outliers : int
        Labelled groups it was trained on, and how many of them are outliers.
    disagreements : int
    backend : str
    version : int
        Counts the models a page trained (the page asks again when it changes).
    """

    booster: Booster
    part: str | None
    held_out: HeldOut
    frames: tuple[tuple[str, int], ...]
    log_sha256: str
    annotators: tuple[str, ...]
    n_groups: int
    n_outliers: int
    disagreements: int = 0
    backend: str = BACKEND
    version: int = 0
    features: tuple[str, ...] = field(default=FEATURES)

    def predict(self, X: np.ndarray) -> np.ndarray:
        """(n,) outlier probability of each group's features."""
        if len(X) == 0:
            return np.zeros(0)
        return self.booster.predict(np.asarray(X, np.float32))

    def applies_to(self, part: str | None, gate: float = GATE) -> str | None:
        """None if its proposals may be pre-filled on a log of ``part``, else the reason why not
        (another part kind, no held-out frame, held-out agreement below ``gate``)."""
        if self.part is not None and part is not None and part != self.part:
            return (f"the assistant was trained on {self.part} and this log is {part}: "
                    "its proposals are shown, nothing is pre-filled")
        if self.held_out.frames == 0:
            return "the assistant has not been checked on a held-out frame yet (label one more frame)"
        return self.below_gate(gate)

    def below_gate(self, gate: float = GATE) -> str | None:
        """None if the held-out agreement reaches ``gate`` (or no frame was held out), else why not."""
        h = self.held_out
        if h.frames and not (h.accuracy >= gate):
            return (f"the assistant agrees with your labels on only {100 * h.accuracy:.0f} % of {h.groups} held-out "
                    f"groups (pre-filling needs {100 * gate:.0f} %): its proposals are shown, nothing is pre-filled")
        return None

    def summary(self) -> str:
        h = self.held_out
        acc = "no held-out frame yet" if h.frames == 0 else (
            f"agrees with your labels {100 * h.accuracy:.0f} % on {h.groups} groups of {h.frames} held-out frame(s)"
            + (f", {100 * h.confident_accuracy:.0f} % on the {h.confident} confident ones" if h.confident else ""))
        return (f"trained on {len(self.frames)} frame(s), {self.n_groups} groups ({self.n_outliers} outliers)"
                f"{' of ' + self.part if self.part else ''}: {acc}")

    def meta(self) -> dict[str, Any]:
        return {"features": list(self.features), "frames": [list(f) for f in self.frames],
                "annotators": list(self.annotators), "n_groups": self.n_groups, "n_outliers": self.n_outliers,
                "disagreements": self.disagreements, "held_out": self.held_out.as_dict()}

    def dumps(self) -> bytes:
        return self.booster.dumps()


def load_model(record: ModelRecord) -> Model:
    """A :class:`Model` from a stored :class:`annotate.store.ModelRecord`.

    Raises
    ------
    TrainingError
        A backend this zcut does not read, or features that are not this zcut's.
    """
    meta = json.loads(record.meta)
    if tuple(meta.get("features", ())) != FEATURES:
        raise TrainingError(f"stored model {record.id} uses other features than this zcut: train it again "
                            "(zcut labels train)")
    booster: Booster
    if record.backend == "lightgbm":
        import lightgbm as lgb

        booster = _Lgb(lgb.Booster(model_str=record.model.decode()))
    elif record.backend == "xgboost":
        import xgboost as xgb

        b = xgb.Booster()
        b.load_model(bytearray(record.model))
        booster = _Xgb(b)
    else:
        raise TrainingError(f"stored model {record.id}: unknown backend {record.backend!r}")
    h = meta.get("held_out", {})
    nan = float("nan")
    held = HeldOut(int(h.get("frames", 0)), int(h.get("groups", 0)),
                   nan if h.get("accuracy") is None else float(h["accuracy"]), int(h.get("confident", 0)),
                   nan if h.get("confident_accuracy") is None else float(h["confident_accuracy"]))
    return Model(booster, record.part, held, tuple((str(t), int(s)) for t, s in meta.get("frames", [])),
                 record.log_sha256, tuple(meta.get("annotators", [])), int(meta.get("n_groups", 0)),
                 int(meta.get("n_outliers", 0)), int(meta.get("disagreements", 0)), record.backend)


def held_out_predictions(ts: TrainingSet, *, backend: str = BACKEND, folds: int = FOLDS) -> np.ndarray:
    """(n,) probability of each labelled group from a model trained without its frame (NaN with one frame)."""
    n_frames = len(ts.frames)
    out = np.full(ts.y.size, np.nan)
    if n_frames < 2:
        return out
    k = min(folds, n_frames)
    fold_of_frame = np.arange(n_frames) % k
    for f in range(k):
        test = fold_of_frame[ts.frame] == f
        train = ~test
        y = ts.y[train]
        m = fit_booster(ts.X[train], y, backend=backend) if 0 < y.sum() < y.size else _single_class(y)
        out[test] = m.predict(ts.X[test])
    return out


def train(ts: TrainingSet, *, part: str | None, log_sha256: str, backend: str = BACKEND, version: int = 0) -> Model:
    """Fit the assistant on a training set, measuring it on held-out frames first.

    Raises
    ------
    TrainingError
        No labelled group, or one class only.
    """
    if ts.y.size == 0:
        extra = f" ({ts.disagreements} groups left out: the annotators disagree on them)" if ts.disagreements else ""
        raise TrainingError("no labelled groups to learn from: decide the groups of at least one frame "
                            f"(accept or reject each) first{extra}")
    n_out = int(ts.y.sum())
    if n_out == 0 or n_out == ts.y.size:
        what = "outliers" if n_out else "not outliers"
        raise TrainingError(f"all {ts.y.size} labelled groups are {what}: the assistant needs both kinds "
                            "(label a frame with groups of the other kind)")
    p = held_out_predictions(ts, backend=backend)
    has = np.isfinite(p)
    if has.any():
        right = (p[has] >= 0.5) == ts.y[has]
        conf = np.maximum(p[has], 1 - p[has]) >= CONFIDENT
        held = HeldOut(len(set(ts.frame[has].tolist())), int(has.sum()), float(right.mean()), int(conf.sum()),
                       float(right[conf].mean()) if conf.any() else float("nan"))
    else:
        held = HeldOut(0, 0, float("nan"), 0, float("nan"))
    booster = fit_booster(ts.X, ts.y, backend=backend)
    return Model(booster, part, held, ts.frames, log_sha256, ts.annotators, int(ts.y.size), n_out,
                 ts.disagreements, backend, version)


def proposals(model: Model | None, features: np.ndarray, *, part: str | None, gate: float = GATE) -> dict[str, Any]:
    """What the page shows for a frame's groups: ``{"model": {...} | None, "p": [...], "prefill": bool,
    "why_not": str | None}``."""
    if model is None:
        return {"model": None, "p": [], "prefill": False, "why_not": None}
    p = model.predict(features)
    why = model.applies_to(part, gate)
    return {"model": {"version": model.version, "summary": model.summary(), "part": model.part,
                      "held_out": model.held_out.as_dict(), "frames": len(model.frames),
                      "confident": CONFIDENT, "gate": gate, "backend": model.backend},
            "p": [round(float(v), 4) for v in p], "prefill": why is None, "why_not": why}


# --------------------------------------------------------------------------- the page's trainer
class Trainer:
    """The page's assistant: retrains in a background thread whenever labels change (:meth:`poke`).

    Until the log's own labels can train a model it uses the store's newest stored model (``zcut
    labels train``), saying which. Every failure is a message on the page (:attr:`message`), never an
    error of a request.

    Parameters
    ----------
    catalogue : annotate.catalogue.Catalogue
        The prepared frames (their groups' features).
    store : annotate.store.LabelStore
    log : annotate.store.LogRecord
    part : str or None
        The log's part kind.
    debounce_s : float
        Labels saved within this many seconds train one model.
    gate : float
        The held-out agreement a model needs before its proposals are pre-filled (:data:`GATE`).
    """

    def __init__(self, catalogue: Catalogue, store: LabelStore, log: LogRecord, *, part: str | None, debounce_s: float = 1.0,
                 gate: float = GATE) -> None:
        import threading

        self.catalogue = catalogue
        self.store = store
        self.log = log
        self.part = part
        self.debounce_s = debounce_s
        self.gate = gate
        self.model: Model | None = None
        self.message = "no labels yet: the assistant learns from the groups you decide"
        self.training = False
        self.version = 0
        self._event = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._cache: dict[tuple[int, int], np.ndarray] = {}
        try:
            rec = store.latest_model(log_sha256=log.sha256) or store.latest_model()
            if rec is not None:
                self.model = load_model(rec)
                self.message = f"stored model {rec.id}: {self.model.summary()}"
        except (TrainingError, ZcutError, ValueError) as e:
            self.message = f"the stored model cannot be used: {e}"
        self._thread = threading.Thread(target=self._run, name="zcut-annotate-assistant", daemon=True)

    def start(self) -> None:
        self._thread.start()
        self.poke()

    def stop(self) -> None:
        self._stop.set()
        self._event.set()
        if self._thread.is_alive():
            self._thread.join(timeout=30)

    def poke(self) -> None:
        """Labels changed: train again (soon)."""
        self._event.set()

    def training_set(self) -> TrainingSet:
        b = TrainingSetBuilder()
        who = self.store.annotators(self.log)
        for sf, rec in self.catalogue.snapshot():
            if sf.n_groups == 0:
                continue
            labels = []
            for a in who:
                lab = self.store.label(rec, annotator=a)
                if lab is not None:
                    decided, share = sf.group_targets(lab.outliers, lab.reviewed)
                    labels.append((a, decided, share))
            b.add((sf.topic, sf.stamp_ns), sf.group_features, labels)
        return b.build()

    def train_now(self) -> None:
        """One training, in the calling thread (the background thread calls it)."""
        self.training = True
        try:
            ts = self.training_set()
            model = train(ts, part=self.part, log_sha256=self.log.sha256, version=self.version + 1)
        except TrainingError as e:
            with self._lock:
                if self.model is None or self.model.log_sha256 != self.log.sha256 or not self.model.frames:
                    self.message = str(e)
                else:
                    self.message = f"{e} (the last model stays)"
            return
        except Exception as e:  # noqa: BLE001 - shown on the page; the page goes on without proposals
            with self._lock:
                self.message = f"training failed: {type(e).__name__}: {e}"
            return
        finally:
            self.training = False
        with self._lock:
            self.version += 1
            self.model = model
            self._cache.clear()
            dis = f"; {ts.disagreements} groups left out (annotators disagree)" if ts.disagreements else ""
            self.message = model.summary() + dis

    def _run(self) -> None:
        while not self._stop.is_set():
            self._event.wait()
            if self._stop.is_set():
                return
            self._stop.wait(self.debounce_s)
            self._event.clear()
            if self._stop.is_set():
                return
            self.train_now()

    def predictions(self, sf: ServedFrame) -> np.ndarray | None:
        """(n_groups,) outlier probabilities of a served frame's groups (None without a model)."""
        with self._lock:
            model = self.model
            key = (sf.index, self.version)
            if model is None:
                return None
            if key in self._cache:
                return self._cache[key]
        p = model.predict(sf.group_features)
        with self._lock:
            self._cache[key] = p
        return p

    def status(self) -> dict[str, Any]:
        with self._lock:
            m = self.model
            return {"version": self.version if m is not None else 0, "training": self.training,
                    "message": self.message, "model": None if m is None else {
                        "summary": m.summary(), "part": m.part, "held_out": m.held_out.as_dict(),
                        "frames": len(m.frames), "backend": m.backend, "confident": CONFIDENT,
                        "gate": self.gate, "why_not": m.applies_to(self.part, self.gate)}}


# --------------------------------------------------------------------------- offline: a log's labels
def page_fits(session: ReplaySession) -> bool:
    """Whether the labelling page fits a part model to the frames of ``session``'s log, as it decides it
    (:func:`annotate.fits.fitter_for`, without reading the mesh): the config's ``explained.part_model``
    (``--part-model FILE``), else the log's ``part_model.ply`` attachment. Its review groups then have no patch
    detector (:func:`annotate.groups.review_groups`' ``fits``), and so must the groups the assistant is trained on
    and the ``learned`` method reads (:func:`frame_groups`)."""
    from replay.logs.part_model import carries_part_model
    from replay.pipeline.explained import NAME

    p = session.config.bank.get(NAME)
    return bool(p is not None and p.part_model) or carries_part_model(session.reader)


def frame_groups(frame: Frame, result: FrameResult, *, config: PipelineConfig,
                 fits: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(features, pixels, starts, group ids) of one replayed frame's review groups, as the page builds them.

    ``fits``: the page fits a part model to the log's frames (:func:`page_fits`); its groups then have no patch
    detector, as the page's (:func:`annotate.groups.review_groups`)."""
    from annotate.groups import review_groups
    from zcut.params import SuspectParams

    valid = np.asarray(result.valid, bool)
    g = review_groups(frame.xyz, frame.rgb, height_mm=np.asarray(result.height_mm, np.float64), valid=valid,
                      zone=np.asarray(result.zone, bool) & valid,
                      above_rim=np.asarray(result.easy_outliers, bool) & valid,
                      outliers={k: np.asarray(v, bool) & valid for k, v in result.outliers.items()},
                      params=SuspectParams(a_max=config.zcut.a_max), fits=bool(fits))
    pix, starts = g.pixels()
    return g.features, pix, starts, g.ids


def training_set_of_log(session: ReplaySession, store: LabelStore, log: LogRecord, *,
                        annotators: Sequence[str] | None = None,
                        progress: Callable[[int, int], object] | None = None) -> TrainingSet:
    """The labelled groups of a log: every frame some annotator labelled, replayed as the page would.

    Parameters
    ----------
    session : replay.pipeline.session.ReplaySession
        The log opened with the page's config (the groups depend on it).
    store : annotate.store.LabelStore
    log : annotate.store.LogRecord
    annotators : sequence of str, optional
        Default: every annotator of the log.
    progress : callable, optional
        ``progress(frame_index, n_groups)`` after each labelled frame.
    """
    from annotate.groups import group_targets

    who = list(annotators) if annotators else store.annotators(log)
    fits = page_fits(session)  # the page's groups of this log (no patch detector with a part model)
    b = TrainingSetBuilder()
    results = session.results()
    try:
        for frame, result in results:
            rec = store.frame(log, topic=frame.topic, stamp_ns=frame.stamp_ns)
            if rec is None:
                continue
            found = [(a, store.label(rec, annotator=a)) for a in who]
            labs = [(a, lab) for a, lab in found if lab is not None]
            if not labs:
                continue
            feats, pix, starts, _ = frame_groups(frame, result, config=session.config, fits=fits)
            b.add((frame.topic, frame.stamp_ns), feats,
                  [(a, *group_targets(pix, starts, lab.outliers, lab.reviewed)) for a, lab in labs])
            if progress is not None:
                progress(frame.index, feats.shape[0])
    finally:
        results.close()
    return b.build()


def learned_mask(model: Model, frame: Frame, result: FrameResult, *, config: PipelineConfig,
                 fits: bool) -> np.ndarray:
    """(H, W) bool: the ``learned`` method's outliers on a frame — the pixels of the review groups the
    model proposes as outliers (``p >= 0.5``); ``fits`` as in :func:`frame_groups` (:func:`page_fits` of the
    frame's log)."""
    feats, _, _, ids = frame_groups(frame, result, config=config, fits=fits)
    if feats.shape[0] == 0:
        return np.zeros(ids.shape, bool)
    out = np.concatenate(([False], model.predict(feats) >= 0.5))
    mask: np.ndarray = out[ids]
    return mask
