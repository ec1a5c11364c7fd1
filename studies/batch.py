"""``zcut batch``: every frame of many logs, counted and scored, in one table (SPEC §6).

``frames.parquet`` has one row per frame (:func:`studies.work.batch_row`: the replay table's counts,
fitness, stage timings, and TP/FP/FN per method over the scored region where truth exists);
``summary.json`` the totals, the per-log losses, the pooled accuracy with intervals and the cost.
"""

from __future__ import annotations

import math
import platform
from pathlib import Path
from typing import Any

from annotate.truth import METHODS
from studies.driver import LogPlan
from studies.work import UnitResult


def frames_table(store):
    """Every finished unit's rows, sorted by log and frame."""
    t = store.table()
    if t.num_rows:
        t = t.sort_by([("log_sha256", "ascending"), ("frame", "ascending")])
    return t


def pooled(table) -> dict[str, Any]:
    """Pooled accuracy per method over the scored frames (micro average) with 95 % intervals over
    frames (:func:`zcut.metrics.pooled_interval`; NaN where too few frames)."""
    import numpy as np

    from zcut.metrics import pooled_interval

    if not table.num_rows or "scored" not in table.column_names:
        return {}
    rows = [r for r in table.to_pylist() if r["scored"]]
    if not rows:
        return {}
    out: dict[str, Any] = {}
    for m in METHODS:
        tp = [r[f"{m}_tp"] for r in rows]
        fp = [r[f"{m}_fp"] for r in rows]
        fn = [r[f"{m}_fn"] for r in rows]
        T, F, N = sum(tp), sum(fp), sum(fn)
        out[m] = {"tp": T, "fp": F, "fn": N, "precision": _ratio(T, T + F), "recall": _ratio(T, T + N),
                  "f1": _ratio(2 * T, 2 * T + F + N), "ci95": pooled_interval(np.array(tp, dtype=np.int64), np.array(fp, dtype=np.int64),
                                                                   np.array(fn, dtype=np.int64))}
    return out


def _ratio(a: int, b: int) -> float | None:
    return a / b if b else None


def summary(plans: list[LogPlan], store, table, results: list[UnitResult], *, executor_name: str,
            workers: int, seconds: float) -> dict[str, Any]:
    """``summary.json``: totals, per-log frames, losses and errors, pooled accuracy, cost."""
    metas = store.metas()
    by_log: dict[str, dict[str, Any]] = {}
    for p in plans:
        by_log[p.sha256 or str(p.path)] = {"log": str(p.path), "sha256": p.sha256, "frames_in_log": p.n_frames,
                                           "frames": 0, "damage": [], "unscored": 0, "errors": [],
                                           "notes": list(p.notes)}
        if p.error:
            by_log[p.sha256 or str(p.path)]["errors"].append(p.error)
    for m in metas.values():
        e = by_log.setdefault(m["sha256"], {"log": m["log"], "sha256": m["sha256"], "frames": 0, "damage": [],
                                            "unscored": 0, "errors": []})
        e["frames"] += m["frames"]
        e["damage"] += m["damage"]
        e["unscored"] += len(m["unscored"])
    for r in results:
        if r.error is not None:
            by_log[r.unit.sha256]["errors"].append(f"frames {r.unit.start}-{r.unit.stop or 'end'}: {r.error}")
    totals: dict[str, Any] = {"logs": len(plans), "frames": int(table.num_rows)}
    for c in ("valid_px", "zcut", "sor", "both", "above_rim", "clusters"):
        totals[c] = int(sum(table.column(c).to_pylist())) if table.num_rows else 0
    this_run = [r for r in results if r.error is None]
    frames_now = sum(r.frames for r in this_run)
    cpu = sum(r.cpu_seconds for r in this_run)
    loss = any(e["damage"] or e["errors"] for e in by_log.values())
    return {
        "totals": totals,
        "accuracy": {"region": None, "pooled": pooled(table)},
        "logs": sorted(by_log.values(), key=lambda e: e["log"]),
        "data_loss": loss,
        "this_run": {"frames": frames_now, "seconds": seconds, "frames_per_s": frames_now / seconds if seconds else None,
                     "cpu_seconds_per_frame": cpu / frames_now if frames_now else None,
                     "peak_rss_mb_per_worker": max((r.peak_rss_mb for r in this_run), default=None),
                     "executor": executor_name, "workers": workers, "host": platform.node()},
    }


def jsonable(obj: Any) -> Any:
    """NaN and ±inf as null, tuples as lists (SPEC §3/§4 JSON)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    return obj


def region_note(summary_: dict, region: str) -> dict:
    summary_["accuracy"]["region"] = region
    return summary_


def log_name(path: str) -> str:
    return Path(path).name
