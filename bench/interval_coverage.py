"""Coverage of the pooled-accuracy intervals, measured by simulation (issue 20, item 1).

The estimand: the pooled (micro-averaged) precision, recall and F1 of a method (z-cut, SOR, union,
intersection) over the population of frames of one part kind, one camera, one config — the ratio of
the counts summed over every frame, e.g. ΣTP / (ΣTP + ΣFP). A report sees n frames of that
population and prints an interval; this benchmark measures how often such intervals hold the
population's figure.

1. **Populations** (``generate``). For each part kind and each seed set, ``zcut synth`` logs of
   independent frames (every frame has its own generator state, ``replay.synth.synthesize.frame_rng``), one bin
   model from five synthetic empty-bin scans (``zcut bin-model``), ``zcut batch`` with the default
   config (the paper's nominal parameters): TP, FP, FN of every method per frame over the zone. The
   counts are cached in ``WORK/counts_KIND_SET.npz`` (the logs are deleted once counted), so reruns
   are cheap, and a larger ``--frames`` adds logs to a population counted before.
2. **Coverage** (``simulate``). From one population (``--set``), draw many samples of n = 3, 6, 12,
   24 frames (with replacement by default: independent frames of the population's distribution, so
   the population's pooled figure is exactly the estimand; ``--without-replacement`` draws subsets),
   compute every candidate interval and count how often it holds the population's pooled figure.
   Candidates: the percentile bootstrap (the former method), BCa, bootstrap-t, Wald/t intervals on
   the linearised ratio (variance HC0/HC2/HC3 — weights of each frame's residual by its leverage
   d_i / Σd —, on the ratio or logit scale), and Fieller's interval (the inverted t test of
   Σ(num_i − r·den_i) = 0). The choices were tuned on the ``tune`` set and are reported on the
   ``heldout`` set.

    .venv/bin/python bench/interval_coverage.py generate [--kinds zinc_nuts,black_nuts] [--frames 160]
    .venv/bin/python bench/interval_coverage.py simulate --set tune [--draws 4000]
    .venv/bin/python bench/interval_coverage.py simulate --set heldout --markdown docs/coverage.md
    .venv/bin/python bench/interval_coverage.py describe      # the per-frame count distributions

``docs/coverage.md`` is the table of the held-out run.
"""

from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ZCUT = [sys.executable, "-m", "cli"]
METHODS = ("zcut", "sor", "union", "intersection")
STATS = ("precision", "recall", "f1")
#: Seed sets: the tune set chose the method's options, the held-out set reports them.
SEED_SETS = {"tune": 710_000, "heldout": 720_000}
NS = (3, 6, 12, 24)


# ------------------------------------------------------------------------------ 1. the populations
def _zcut(*args) -> None:
    out = subprocess.run([*ZCUT, *map(str, args)], cwd=ROOT, check=False, stdout=subprocess.DEVNULL)
    if out.returncode not in (0, 3):
        sys.exit(f"zcut {' '.join(map(str, args))} failed with {out.returncode}")


#: Every kind's seeds are offset by its place here (independent of the order of --kinds).
KIND_ORDER = ("spheres", "zinc_nuts", "rods", "black_screws", "black_nuts", "sprockets")


def counts_path(work: Path, kind: str, set_name: str, size: str) -> Path:
    return work / f"counts_{kind}_{set_name}_{size}.npz"


def seed_of(set_name: str, kind: str, log: int) -> int:
    return SEED_SETS[set_name] + 1000 * KIND_ORDER.index(kind) + log


def generate(args) -> int:
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    model = work / f"bin_{args.size}.ply"
    if not model.is_file():
        empty = work / "empty.mcap"
        _zcut("synth", "-o", empty, "--empty", "--frames", 5, "--seed", 7, "--size", args.size, "--force")
        _zcut("bin-model", empty, "-o", model, "--force")
        empty.unlink()
    per_log = args.frames_per_log
    n_logs = -(-args.frames // per_log)
    for set_name in args.sets.split(","):
        for kind in args.kinds.split(","):
            dest = counts_path(work, kind, set_name, args.size)
            part = work / f"part_{kind}_{set_name}_{args.size}"
            if dest.is_file():
                have = np.load(dest)["seeds"]
                if have.size >= n_logs:
                    continue
                # a bigger population: its first logs are counted already (the per-log tables back)
                part.mkdir(exist_ok=True)
                full = pq.read_table(dest.with_suffix(".parquet"))
                for s in have:
                    pq.write_table(full.filter(pc.equal(full.column("log"), f"{kind}_{s}.mcap")),
                                   part / f"{s}.parquet")
                print(f"{kind} {set_name}: {have.size} logs counted, growing to {n_logs}", file=sys.stderr)
            part.mkdir(exist_ok=True)
            t0 = time.perf_counter()
            for g in range(0, n_logs, args.workers):
                seeds = [seed_of(set_name, kind, j) for j in range(g, min(n_logs, g + args.workers))]
                done = [part / f"{s}.parquet" for s in seeds]
                if all(p.is_file() for p in done):
                    continue
                logs = [part / f"{kind}_{s}.mcap" for s in seeds]
                procs = [subprocess.Popen([*ZCUT, "synth", "-o", str(log), "--parts", kind, "--frames", str(per_log),
                                           "--seed", str(s), "--size", args.size, "--force"], cwd=ROOT,
                                          stdout=subprocess.DEVNULL)
                         for log, s in zip(logs, seeds)]
                if any(p.wait() != 0 for p in procs):
                    sys.exit(f"zcut synth failed for {kind} seeds {seeds}")
                out = part / "batch"
                shutil.rmtree(out, ignore_errors=True)
                _zcut("batch", *logs, "-o", out, "--bin-model", model, "--workers", args.workers)
                table = pq.read_table(out / "frames.parquet")
                for log, p in zip(logs, done):
                    mine = table.filter(pc.equal(table.column("log"), log.name))
                    if mine.num_rows != per_log or not all(mine.column("scored").to_pylist()):
                        sys.exit(f"{log}: {mine.num_rows} rows, expected {per_log} scored frames")
                    pq.write_table(mine, p)
                    log.unlink()
                shutil.rmtree(out, ignore_errors=True)
                print(f"{kind} {set_name}: logs {g + len(seeds)}/{n_logs} ({time.perf_counter() - t0:.0f} s)",
                      file=sys.stderr, flush=True)
            seeds = [seed_of(set_name, kind, j) for j in range(n_logs)]
            full = pa.concat_tables([pq.read_table(part / f"{s}.parquet") for s in seeds])
            pq.write_table(full, dest.with_suffix(".parquet"))
            rows = full.to_pylist()
            arr = {f"{m}_{c}": np.array([r[f"{m}_{c}"] for r in rows], dtype=np.int64)
                   for m in METHODS for c in ("tp", "fp", "fn")}
            np.savez(dest, size=args.size, seeds=np.array(seeds), **arr)
            shutil.rmtree(part)
            print(f"{kind} {set_name}: {len(rows)} frames -> {dest}", file=sys.stderr, flush=True)
    return 0


def load_counts(work: Path, kind: str, set_name: str, size: str) -> dict[str, np.ndarray]:
    """``{method: (3, n_frames) int64}`` rows tp, fp, fn."""
    z = np.load(counts_path(work, kind, set_name, size))
    return {m: np.stack([z[f"{m}_{c}"] for c in ("tp", "fp", "fn")]) for m in METHODS}


# ------------------------------------------------------------------------------ 2. the candidates
RATIOS = {"precision": lambda t, f, n: (t, t + f), "recall": lambda t, f, n: (t, t + n),
          "f1": lambda t, f, n: (2 * t, 2 * t + f + n)}


def _ratio_rows(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    sn, sd = num.sum(-1), den.sum(-1)
    return np.divide(sn, sd, out=np.full(sn.shape, np.nan), where=sd > 0)


def _residuals(num: np.ndarray, den: np.ndarray):
    """(frames n, Σden, the pooled ratio R, each frame's residual z_i = num_i − R·den_i, its leverage
    h_i = den_i/Σden) of rows of frames."""
    n = num.shape[-1]
    sd = den.sum(-1)
    r = _ratio_rows(num, den)
    z = num - np.nan_to_num(r)[..., None] * den
    h = np.divide(den, sd[..., None], out=np.zeros_like(den), where=sd[..., None] > 0)
    return n, sd, r, z, h


def linearised(num, den, *, level, hc="hc1", scale="ratio", quantile="t"):
    """Wald/t interval of the pooled ratio Σnum/Σden from its linearisation over frames.

    Each frame's residual z_i = num_i − R·den_i; var(R) ≈ Σ w_i z_i² / (Σden)² with w_i = n/(n−1)
    (hc1), 1/(1−h_i) (hc2) or 1/(1−h_i)² (hc3), h_i = den_i/Σden the frame's leverage (hc0: 1).
    ``scale = "logit"`` builds the interval on logit(R) (se / (R(1−R))) and maps it back.
    """
    n, sd, r, z, h = _residuals(num, den)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = {"hc0": np.ones_like(h), "hc1": np.full_like(h, n / max(n - 1, 1)), "hc2": 1.0 / (1.0 - h),
             "hc3": 1.0 / (1.0 - h) ** 2}[hc]
        w = np.where(z == 0, 0.0, w)  # a frame that fits exactly adds nothing (h = 1 with z = 0)
        se = np.sqrt((w * z * z).sum(-1)) / sd
    q = _quantile(level, n, quantile)
    if scale == "logit":
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.log(r / (1 - r))
            sg = se / (r * (1 - r))
            lo, hi = _expit(g - q * sg), _expit(g + q * sg)
        edge = (r <= 0) | (r >= 1)  # logit undefined: fall back to the ratio scale
        lo = np.where(edge, r - q * se, lo)
        hi = np.where(edge, r + q * se, hi)
    else:
        lo, hi = r - q * se, r + q * se
    return np.clip(lo, 0, 1), np.clip(hi, 0, 1)


def bm_df(den, power: int = 1):
    """Bell–McCaffrey degrees of freedom of the hc2 (``power`` 1) or hc3 (2) variance of Σnum/Σden.

    The ratio is the weighted least-squares slope of num on den with weights 1/den (frames with
    den = 0 carry no weight); its variance estimate is a quadratic form ε'Aε of the errors, A = M C M
    with M = I − u u' (u_i = √h_i, h_i = den_i / Σden) and C = diag(h_i / (1 − h_i)^power). Under
    independent errors of equal variance (the working model), Satterthwaite's approximation gives
    df = tr(A)² / tr(A²): n − 1 for equal frames (hc2), less when a few frames hold most of Σden.
    A_ij = c_i δ_ij + u_i u_j (s − c_i − c_j) with s = Σ h c, so both traces are sums over frames.
    """
    sd = den.sum(-1, keepdims=True)
    h = np.divide(den, sd, out=np.zeros_like(den), where=sd > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(h < 1, h / (1 - h) ** power, np.inf)
        s = (h * c).sum(-1, keepdims=True)
        m2 = (h * c * c).sum(-1)
        tr = c.sum(-1) - s[..., 0]
        diag = c + h * (s - 2 * c)
        tr2 = (diag * diag).sum(-1) + 2 * m2 - s[..., 0] ** 2 - (h * h * (s - 2 * c) ** 2).sum(-1)
        return np.where(np.isfinite(tr) & (tr2 > 0), tr * tr / tr2, np.nan)


def bell_mccaffrey(num, den, *, level, scale="ratio", hc="hc2", df_rule="bm", df_scale=1.0):
    """:func:`linearised` with the hc2 (or hc3) variance and a t quantile of :func:`bm_df` degrees of
    freedom (``df_rule = "bm"``), or of the smaller of that and the effective number of frames of the
    variance terms, (Σ v_i)² / Σ v_i² with v_i = c_i z_i² (``"min"``: few frames holding most of the
    variance give few degrees of freedom; ``"min1"``: that effective number times (m − 1) / m, m the
    frames that define the ratio, so that equal frames give m − 1 as Bell–McCaffrey does);
    ``df_scale`` multiplies the result."""
    from scipy import stats

    n, sd, r, z, h = _residuals(num, den)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(z == 0, 0.0, 1.0 / (1.0 - h) ** (2 if hc == "hc3" else 1))
        se = np.sqrt((w * z * z).sum(-1)) / sd
    df = bm_df(den, 2 if hc == "hc3" else 1)
    if df_rule in ("min", "min1"):
        v = w * z * z
        with np.errstate(divide="ignore", invalid="ignore"):
            emp = v.sum(-1) ** 2 / (v * v).sum(-1)
            if df_rule == "min1":
                m = (den > 0).sum(-1)
                emp = emp * (m - 1) / m
        df = np.where(np.isfinite(emp), np.fmin(df, emp), df)
    df = df * df_scale
    q = np.where(np.isnan(df), np.nan, stats.t.ppf((1 + level) / 2, np.where(np.isnan(df), 1, df)))
    del n
    if scale == "logit":
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.log(r / (1 - r))
            sg = se / (r * (1 - r))
            lo, hi = _expit(g - q * sg), _expit(g + q * sg)
        edge = (r <= 0) | (r >= 1)
        lo = np.where(edge, r - q * se, lo)
        hi = np.where(edge, r + q * se, hi)
    else:
        lo, hi = r - q * se, r + q * se
    return np.clip(lo, 0, 1), np.clip(hi, 0, 1)


def _expit(x):
    return 0.5 * (1 + np.tanh(0.5 * x))


def _quantile(level, n, kind):
    from scipy import stats

    p = (1 + level) / 2
    if kind == "z":
        return float(stats.norm.ppf(p))
    return float(stats.t.ppf(p, max(n - 1, 1)))


def fieller(num, den, *, level, quantile="t"):
    """The ratios r whose t test of mean(num_i − r·den_i) = 0 does not reject (Fieller's interval),
    within [0, 1]: (Σw)² ≤ q² · n/(n−1) · Σ(w_i − w̄)² with w_i = num_i − r·den_i, a quadratic in r."""
    n = num.shape[-1]
    q2 = _quantile(level, n, quantile) ** 2
    xn, xd = num - num.mean(-1, keepdims=True), den - den.mean(-1, keepdims=True)
    snn, sdd, snd = (xn * xn).sum(-1), (xd * xd).sum(-1), (xn * xd).sum(-1)
    c = q2 * n / max(n - 1, 1)
    mn, md = num.sum(-1), den.sum(-1)
    # (mn − r md)² − c (snn − 2 r snd + r² sdd) ≤ 0  ->  A r² + B r + C ≤ 0
    A = md * md - c * sdd
    B = -2 * mn * md + 2 * c * snd
    C = mn * mn - c * snn
    disc = B * B - 4 * A * C
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0))
        r1, r2 = (-B - sq) / (2 * A), (-B + sq) / (2 * A)
    lo, hi = np.minimum(r1, r2), np.maximum(r1, r2)
    bounded = (A > 0) & (disc >= 0)
    lo = np.where(bounded, np.clip(lo, 0, 1), 0.0)  # unbounded or exclusive sets: all of [0, 1]
    hi = np.where(bounded, np.clip(hi, 0, 1), 1.0)
    r = _ratio_rows(num, den)
    lo, hi = np.where(np.isnan(r), np.nan, lo), np.where(np.isnan(r), np.nan, hi)
    return lo, hi


def score(num, den, *, level, hc="hc1", quantile="t"):
    """The ratios r whose score test does not reject: (Σ w_i)² ≤ q² Σ c_i w_i² with w_i = num_i − r·den_i
    (uncentred: under the hypothesis E w = 0) and c_i the hc weights of :func:`linearised` — a quadratic
    in r; within [0, 1]."""
    n = num.shape[-1]
    q2 = _quantile(level, n, quantile) ** 2
    sd = den.sum(-1, keepdims=True)
    h = np.divide(den, sd, out=np.zeros_like(den), where=sd > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = {"hc0": np.ones_like(h), "hc1": np.full_like(h, n / max(n - 1, 1)),
             "hc2": 1.0 / (1.0 - h), "hc3": 1.0 / (1.0 - h) ** 2}[hc]
    c = np.where(np.isfinite(c), c, 1e12)
    mn, md = num.sum(-1), den.sum(-1)
    A = md * md - q2 * (c * den * den).sum(-1)
    B = -2 * mn * md + 2 * q2 * (c * num * den).sum(-1)
    C = mn * mn - q2 * (c * num * num).sum(-1)
    return _quadratic_set(A, B, C, _ratio_rows(num, den))


def _quadratic_set(A, B, C, r):
    """{x in [0, 1] : A x² + B x + C ≤ 0} as (lo, hi), its hull when it is two pieces; NaN where r is."""
    disc = B * B - 4 * A * C
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0))
        r1, r2 = (-B - sq) / (2 * A), (-B + sq) / (2 * A)
    lo, hi = np.minimum(r1, r2), np.maximum(r1, r2)
    bounded = (A > 0) & (disc >= 0)
    lo = np.where(bounded, np.clip(lo, 0, 1), 0.0)
    hi = np.where(bounded, np.clip(hi, 0, 1), 1.0)
    return np.where(np.isnan(r), np.nan, lo), np.where(np.isnan(r), np.nan, hi)


def _boot_weights(n: int, n_boot: int, seed: int) -> np.ndarray:
    from zcut.metrics import bootstrap_weights

    return bootstrap_weights(n, n_boot=n_boot, seed=seed)


def percentile_boot(num, den, *, level, n_boot=999, seed=0):
    wt = _boot_weights(num.shape[-1], n_boot, seed).T
    rs = _safe_div(num @ wt, den @ wt)
    return np.nanquantile(rs, (1 - level) / 2, axis=-1), np.nanquantile(rs, (1 + level) / 2, axis=-1)


def _safe_div(a, b):
    return np.divide(a, b, out=np.full(np.broadcast(a, b).shape, np.nan), where=b > 0)


def bca(num, den, *, level, n_boot=999, seed=0):
    """Efron's BCa: bias from the share of resamples below R, acceleration from the jackknife."""
    from scipy import stats

    n = num.shape[-1]
    wt = _boot_weights(n, n_boot, seed).T
    rs = _safe_div(num @ wt, den @ wt)
    r = _ratio_rows(num, den)
    ok = ~np.isnan(rs)
    k = ok.sum(-1)
    below = ((rs < r[:, None]) & ok).sum(-1) + 0.5 * ((rs == r[:, None]) & ok).sum(-1)
    z0 = stats.norm.ppf(np.clip(below / np.maximum(k, 1), 1e-6, 1 - 1e-6))
    jn = num.sum(-1, keepdims=True) - num
    jd = den.sum(-1, keepdims=True) - den
    jack = _safe_div(jn, jd)
    d = np.nanmean(jack, -1, keepdims=True) - jack
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.nansum(d ** 3, -1) / (6 * np.nansum(d ** 2, -1) ** 1.5)
    a = np.nan_to_num(a)
    out = []
    for p in ((1 - level) / 2, (1 + level) / 2):
        zp = stats.norm.ppf(p)
        adj = stats.norm.cdf(z0 + (z0 + zp) / (1 - a * (z0 + zp)))
        s = np.sort(np.where(ok, rs, np.inf), -1)
        idx = np.clip(np.floor(adj * (k - 1) + 0.5).astype(np.int64), 0, np.maximum(k - 1, 0))
        out.append(np.where(k > 0, np.take_along_axis(s, idx[:, None], -1)[:, 0], np.nan))
    return out[0], out[1]


def boot_t(num, den, *, level, n_boot=999, seed=0):
    """Bootstrap-t with the linearised (hc1) standard error in every resample."""
    n = num.shape[-1]
    W = _boot_weights(n, n_boot, seed)  # (B, n)
    r = _ratio_rows(num, den)
    sd = den.sum(-1)
    z = num - np.nan_to_num(r)[:, None] * den
    se = np.sqrt((z * z).sum(-1) * n / max(n - 1, 1)) / sd
    sn, sdd = num @ W.T, den @ W.T
    rs = _safe_div(sn, sdd)
    # resampled se: Σ_b-frames w_ib (num_i − r*_b den_i)² ; expand the square
    nn, nd, dd = (num * num) @ W.T, (num * den) @ W.T, (den * den) @ W.T
    rr = np.nan_to_num(rs)
    ses = np.sqrt(np.maximum(nn - 2 * rr * nd + rr * rr * dd, 0) * n / max(n - 1, 1)) / np.where(sdd > 0, sdd, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = (rs - r[:, None]) / ses
    ts = np.where(np.isnan(ts), np.nan, ts)
    lo_q = np.nanquantile(np.where(np.isinf(ts), np.sign(ts) * 1e12, ts), (1 + level) / 2, axis=-1)
    hi_q = np.nanquantile(np.where(np.isinf(ts), np.sign(ts) * 1e12, ts), (1 - level) / 2, axis=-1)
    return np.clip(r - lo_q * se, 0, 1), np.clip(r - hi_q * se, 0, 1)


def candidates(level: float) -> dict:
    from functools import partial

    out = {"percentile bootstrap": partial(percentile_boot, level=level),
           "BCa": partial(bca, level=level),
           "bootstrap-t": partial(boot_t, level=level),
           "Fieller t": partial(fieller, level=level)}
    for hc in ("hc1", "hc2", "hc3"):
        for scale in ("ratio", "logit"):
            out[f"linearised {hc} {scale} t"] = partial(linearised, level=level, hc=hc, scale=scale)
    for hc in ("hc2", "hc3"):
        for scale in ("ratio", "logit"):
            out[f"BM {hc} {scale}"] = partial(bell_mccaffrey, level=level, hc=hc, scale=scale)
            out[f"BM-min {hc} {scale}"] = partial(bell_mccaffrey, level=level, hc=hc, scale=scale, df_rule="min")
    out["BM-min1 hc3 logit"] = partial(bell_mccaffrey, level=level, hc="hc3", scale="logit", df_rule="min1")
    for f in (0.75, 0.5):
        out[f"BM-min hc3 logit df×{f}"] = partial(bell_mccaffrey, level=level, hc="hc3", scale="logit",
                                                 df_rule="min", df_scale=f)
    out["linearised hc1 ratio z"] = partial(linearised, level=level, hc="hc1", scale="ratio", quantile="z")
    return out


# ------------------------------------------------------------------------------ 3. coverage
def draw_indices(n_pop: int, n: int, draws: int, rng, replace: bool) -> np.ndarray:
    if replace:
        return rng.integers(0, n_pop, size=(draws, n))
    return np.argsort(rng.random((draws, n_pop)), axis=-1)[:, :n]


#: The interval zcut computes (zcut.metrics.pooled_interval_many, with its no-interval rule).
CHOSEN = "zcut: logit t, hc3, df min(BM, effective frames)"
BASELINE = "percentile bootstrap"


def coverage_rows(pop: dict, *, kind, ns, draws, seed, replace, level, which=None):
    """One row per (candidate, method, statistic, n): coverage among draws with an interval, the
    share of draws without one, mean width. The same draws for every candidate."""
    from zcut.metrics import pooled_interval_many

    cands = candidates(level)
    names = [CHOSEN, *cands]
    if which:
        names = [k for k in names if k in which]
    rows = []
    rng = np.random.default_rng(seed)
    for n in ns:
        for m in METHODS:
            t, f, fn = pop[m]
            idx = draw_indices(t.size, n, draws, rng, replace)
            st, sf, sfn = t[idx], f[idx], fn[idx]
            chosen = pooled_interval_many(st, sf, sfn, level=level) if CHOSEN in names else None
            for stat in STATS:
                pnum, pden = RATIOS[stat](t.astype(np.float64), f.astype(np.float64), fn.astype(np.float64))
                truth = pnum.sum() / pden.sum()
                num, den = RATIOS[stat](st.astype(np.float64), sf.astype(np.float64), sfn.astype(np.float64))
                for name in names:
                    if name == CHOSEN:
                        lo, hi = chosen[stat][:, 0], chosen[stat][:, 1]
                    else:
                        lo, hi = cands[name](num, den)
                    has = ~(np.isnan(lo) | np.isnan(hi))
                    held = (lo <= truth) & (truth <= hi)
                    rows.append({"kind": kind, "candidate": name, "method": m, "stat": stat, "n": n,
                                 "truth": float(truth), "draws": draws,
                                 "coverage": float(held[has].mean()) if has.any() else math.nan,
                                 "none": float(1 - has.mean()),
                                 "width": float(np.mean(hi[has] - lo[has])) if has.any() else math.nan})
    return rows


def rule_rows(pop: dict, *, kind, ns, draws, seed, replace, level):
    """What the no-interval rule removes: per (method, statistic, n), the share of samples it withholds
    and how often the same formula without the rule (:func:`bell_mccaffrey`, ``df_rule = "min1"``; a
    zero-width interval where every frame has the same figure) would have held the population's figure
    in those samples, and over all samples."""
    from zcut.metrics import pooled_interval_many

    out = []
    rng = np.random.default_rng(seed + 1)
    for n in ns:
        for m in METHODS:
            t, f, fn = pop[m]
            idx = draw_indices(t.size, n, draws, rng, replace)
            got = pooled_interval_many(t[idx], f[idx], fn[idx], level=level)
            for stat in STATS:
                pnum, pden = RATIOS[stat](*(a.astype(np.float64) for a in (t, f, fn)))
                truth = pnum.sum() / pden.sum()
                num, den = RATIOS[stat](*(a[idx].astype(np.float64) for a in (t, f, fn)))
                lo, hi = bell_mccaffrey(num, den, level=level, scale="logit", hc="hc3", df_rule="min1")
                defined = den.sum(-1) > 0
                withheld = np.isnan(got[stat][:, 0]) & defined
                held = (lo <= truth) & (truth <= hi)
                ok = defined & ~np.isnan(lo)
                out.append({"kind": kind, "method": m, "stat": stat, "n": n, "withheld": float(withheld.mean()),
                            "withheld_coverage": float(held[withheld].mean()) if withheld.any() else math.nan,
                            "coverage_without_rule": float(held[ok].mean()) if ok.any() else math.nan,
                            "width_without_rule": float(np.mean(hi[ok] - lo[ok])) if ok.any() else math.nan})
    return out


def simulate(args) -> int:
    import json

    work = Path(args.work)
    rows = []
    t0 = time.process_time()
    for kind in args.kinds.split(","):
        pop = load_counts(work, kind, args.set, args.size)
        rows += coverage_rows(pop, kind=kind, ns=NS, draws=args.draws, seed=args.seed,
                              replace=not args.without_replacement, level=0.95,
                              which=args.candidates.split(";") if args.candidates else None)
    summarise(rows)
    rules = []
    if not args.candidates:
        for kind in args.kinds.split(","):
            rules += rule_rows(load_counts(work, kind, args.set, args.size), kind=kind, ns=(2, *NS), draws=args.draws,
                               seed=args.seed, replace=not args.without_replacement, level=0.95)
        for r in rules:
            if r["withheld"] > 0:
                print(f"rule: {r['kind']} {r['method']} {r['stat']} n={r['n']}: withheld {r['withheld']:.3f}, "
                      f"their coverage without the rule {r['withheld_coverage']:.3f}", file=sys.stderr)
    out = work / f"coverage_{args.set}{'_worep' if args.without_replacement else ''}.json"
    out.write_text(json.dumps({"rows": rows, "rules": rules}))
    args.rules = rules
    print(f"{len(rows)} cells, {time.process_time() - t0:.0f} CPU-s; rows in {out}", file=sys.stderr)
    if args.markdown:
        Path(args.markdown).write_text(markdown(rows, args, work))
    return 0


def summarise(rows, out=None) -> list[str]:
    """Per candidate and n: the worst coverage, cells below 0.93, the mean width (printed, and returned
    as Markdown table lines)."""
    names = list(dict.fromkeys(r["candidate"] for r in rows))
    lines = ["| interval | " + " | ".join(f"n = {n}: min coverage, cells < 0.93, mean width" for n in NS) + " |",
             "|---|" + "---|" * len(NS)]
    print(f"{'candidate':44s} " + " ".join(f"{'n=' + str(n) + ' min/#<.93/width':>24s}" for n in NS))
    for c in names:
        cells, md = [], []
        for n in NS:
            sel = [r for r in rows if r["candidate"] == c and r["n"] == n and r["coverage"] == r["coverage"]]
            if not sel:
                cells.append(f"{'-':>24s}")
                md.append("—")
                continue
            mn = min(r["coverage"] for r in sel)
            bad = sum(r["coverage"] < 0.93 for r in sel)
            w = np.mean([r["width"] for r in sel])
            cells.append(f"{mn:8.3f} {bad:3d}/{len(sel):<3d} {w:8.3f}")
            md.append(f"{mn:.3f}, {bad}/{len(sel)}, {w:.3f}")
        print(f"{c:44s} " + " ".join(cells))
        lines.append(f"| {c} | " + " | ".join(md) + " |")
    return lines


def describe_population(work: Path, kinds, set_name: str, size: str) -> list[str]:
    """Markdown: per kind and method, the population's pooled figures and how its counts spread."""
    lines = ["| kind | filter | frames | pooled precision | pooled recall | pooled F1 | TP per frame: median (5–95 %) "
             "| FP per frame: median (5–95 %), share of ΣFP in the top 10 % of frames | FN per frame: median (5–95 %) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for kind in kinds:
        pop = load_counts(work, kind, set_name, size)
        for m in METHODS:
            t, f, fn = (a.astype(np.float64) for a in pop[m])

            def spread(a):
                p5, p50, p95 = np.percentile(a, [5, 50, 95])
                return f"{p50:.0f} ({p5:.0f}–{p95:.0f})"

            top = np.sort(f)[-max(1, f.size // 10):].sum() / max(f.sum(), 1)
            lines.append(f"| {kind} | {m} | {t.size} | {t.sum() / (t + f).sum():.3f} | {t.sum() / (t + fn).sum():.3f} "
                         f"| {2 * t.sum() / (2 * t + f + fn).sum():.3f} | {spread(t)} | {spread(f)}, {top:.2f} "
                         f"| {spread(fn)} |")
    return lines


def population_sizes(work: Path, kinds, set_name: str, size: str) -> dict[str, tuple[int, int]]:
    """``{kind: (frames, logs)}`` of one seed set's populations."""
    out = {}
    for kind in kinds:
        z = np.load(counts_path(work, kind, set_name, size))
        out[kind] = (int(z["zcut_tp"].size), int(z["seeds"].size))
    return out


#: What a coverage cell says when the rule gave no interval in any sample.
NO_INTERVAL = "too few frames"


def _percent(share: float) -> str:
    """A share as a percentage, "< 0.1 %" rather than 0.0 % when it is not zero."""
    return "0 %" if share == 0 else f"{100 * share:.1f} %" if share >= 0.0005 else "< 0.1 %"


def _cell(r: dict | None) -> str:
    """One coverage cell: the coverage (✗ below 0.93), the share of samples without an interval."""
    if r is None:
        return "—"
    if not r["coverage"] == r["coverage"]:
        return NO_INTERVAL
    text = f"{r['coverage']:.3f}" + (" ✗" if r["coverage"] < 0.93 else "")
    if r["none"] > 0:
        text += f" (no interval in {_percent(r['none'])})"
    return text


def coverage_grid(rows, rules=()) -> list[str]:
    """Markdown: zcut's interval, one row per part kind, filter and figure, coverage at every n (and
    at n = 2, where the rule gives none, when ``rules`` measured it)."""
    chosen = {(r["kind"], r["method"], r["stat"], r["n"]): r for r in rows if r["candidate"] == CHOSEN}
    two = {(r["kind"], r["method"], r["stat"]) for r in rules if r["n"] == 2 and r["withheld"] == 1.0}
    kinds = list(dict.fromkeys(k for k, *_ in chosen))
    lines = ["| kind | filter | figure | population figure | "
             + ("n = 2 | " if two else "") + " | ".join(f"n = {n}" for n in NS) + " |",
             "|---|---|---|---|" + ("---|" if two else "") + "---|" * len(NS)]
    for kind in kinds:
        for m in METHODS:
            for stat in STATS:
                first = next((chosen[kind, m, stat, n] for n in NS if (kind, m, stat, n) in chosen), None)
                truth = f"{first['truth']:.3f}" if first else "—"
                lines.append(f"| {kind} | {m} | {stat} | {truth} | "
                             + (f"{NO_INTERVAL} | " if two and (kind, m, stat) in two else ("— | " if two else ""))
                             + " | ".join(_cell(chosen.get((kind, m, stat, n))) for n in NS) + " |")
    return lines


def chosen_by_n(rows) -> list[dict]:
    """Per n, zcut's interval over every kind, filter and figure: the worst cell, the cells below
    0.93, the mean width and the largest share of samples without an interval."""
    out = []
    for n in NS:
        sel = [r for r in rows if r["candidate"] == CHOSEN and r["n"] == n]
        ok = [r for r in sel if r["coverage"] == r["coverage"]]
        worst = min(ok, key=lambda r: r["coverage"]) if ok else None
        out.append({"n": n, "cells": len(sel), "worst": worst,
                    "below": [r for r in ok if r["coverage"] < 0.93],
                    "width": float(np.mean([r["width"] for r in ok])) if ok else math.nan,
                    "none": max((r["none"] for r in sel), default=math.nan)})
    return out


def markdown(rows, args, work: Path) -> str:
    kinds = list(dict.fromkeys(r["kind"] for r in rows))
    by = {(r["candidate"], r["kind"], r["method"], r["stat"], r["n"]): r for r in rows}
    chosen = [r for r in rows if r["candidate"] == CHOSEN]
    sizes = population_sizes(work, kinds, args.set, args.size)
    other_sizes = population_sizes(work, [k for k in kinds if counts_path(work, k, "tune", args.size).is_file()],
                                   "tune", args.size) if args.set != "tune" else {}
    per_n = chosen_by_n(rows)
    below = [r for s in per_n for r in s["below"]]
    rules = getattr(args, "rules", None) or []
    lines = [
        "# Coverage of the pooled-accuracy intervals, measured",
        "",
        f"Generated by `bench/interval_coverage.py simulate --set {args.set} --kinds {args.kinds} --draws {args.draws} "
        f"--seed {args.seed} --markdown docs/coverage.md` (the populations by `bench/interval_coverage.py generate`). "
        "What the interval is and how to read it: `docs/accuracy.md`, \"Uncertainty\".",
        "",
        "## How it was measured",
        "",
        "- **Estimand**: the pooled (micro-averaged) precision, recall and F1 of a filter over the population of "
        "frames of one part kind (one camera, one config): ΣTP / (ΣTP + ΣFP), ΣTP / (ΣTP + ΣFN), "
        "2ΣTP / (2ΣTP + ΣFP + ΣFN) over every frame.",
        "- **Populations**: per part kind, "
        + ", ".join(f"{kind} {frames} frames ({logs} logs)" for kind, (frames, logs) in sizes.items())
        + f", independent synthetic frames at {args.size} (the "
        "sensor's size) from `zcut synth` (every frame has its own generator state), replayed by `zcut batch` with a "
        "bin model built by `zcut bin-model` from five synthetic empty-bin scans, the default config (the paper's "
        "nominal Δd 0.2 mm, d_max 30 mm, ρ_thr 0.07; SOR on the top of the pile), TP/FP/FN per frame over the zone. "
        f"Two seed sets: `tune` (seeds {SEED_SETS['tune']}+, where the interval's choices were made"
        + "".join(f"; {k} {v[0]} frames" for k, v in other_sizes.items())
        + f") and `heldout` (seeds {SEED_SETS['heldout']}+); this table is the `{args.set}` set. "
        "Log seeds: `SEED_SET + 1000·kind index + log`, 8 frames per log; "
        "every frame's generator is seeded by (log seed, frame index) (`replay.synth.synthesize.frame_rng`), so the two sets share no "
        "frame.",
        f"- **Samples**: {args.draws} samples of n = 3, 6, 12, 24 frames per kind, filter and n, drawn "
        + ("without replacement" if args.without_replacement else
           "with replacement from the population (independent frames of the population's distribution: its pooled "
           "figure is exactly the estimand, no finite-population correction)")
        + f", generator seed {args.seed}; the same samples for every interval. Coverage = the share of samples whose "
        "95 % interval holds the population's figure, among the samples that get an interval; Monte Carlo standard "
        f"error ≈ {math.sqrt(0.95 * 0.05 / args.draws):.4f} at 0.95.",
        *([f"- **Note**: {args.note}"] if getattr(args, "note", None) else []),
        "- **No interval**: zcut prints \"too few frames\" instead of an interval when fewer than 3 frames define "
        "the figure, or every frame that defines it has the same value (`zcut.metrics.pooled_interval_many`); the "
        "column *no interval* is the share of samples where that happened.",
        "",
        "## Coverage of zcut's interval",
        "",
        f"Share of the {args.draws} samples whose 95 % interval holds the population's figure, per part kind, filter "
        "(z-cut, SOR, their union, their intersection), figure and number of frames n; ✗ marks a cell below 0.93; "
        f"\"{NO_INTERVAL}\" where the rule gives no interval in any sample; \"no interval in x %\" where it gave "
        "none in some samples (the coverage is over the others).",
        "",
        *coverage_grid(rows, rules),
        "",
        "Over every kind, filter and figure:",
        "",
        "| n | cells | worst coverage (cell) | cells below 0.93 | mean width | most samples without an interval |",
        "|---|---|---|---|---|---|",
        *(f"| {s['n']} | {s['cells']} | "
          + (f"{s['worst']['coverage']:.3f} ({s['worst']['kind']} {s['worst']['method']} {s['worst']['stat']})"
             if s["worst"] else NO_INTERVAL)
          + f" | {len(s['below'])} | {s['width']:.3f} | {_percent(s['none'])} |" for s in per_n),
        "",
        (f"**Below 0.93 on this set**: {len(below)} of {len(chosen)} cells — "
         + "; ".join(f"{r['kind']} {r['method']} {r['stat']} at n = {r['n']}: {r['coverage']:.3f}" for r in below)
         + ". The interval was not re-tuned on this set (it is the held-out set: changing the method to fit it "
           "would make it a second tuning set)."
         if below else
         f"**Every cell at or above 0.93 on this set** ({len(chosen)} cells)."),
        "",
        "## The populations",
        "",
        *describe_population(work, kinds, args.set, args.size),
        "",
        "## Every interval tried (same samples)",
        "",
        "Worst coverage over the 4 filters × 3 figures × kinds, the number of those cells below 0.93, and the mean "
        "width, per n. The first row is zcut's interval; `percentile bootstrap` is the former one.",
        "",
        *summarise([r for r in rows]),
        "",
    ]
    if rules:
        two = [r for r in rules if r["n"] == 2]
        some = [r for r in rules if r["n"] > 2 and r["withheld"] > 0]
        lines += [
            "## The no-interval rule, measured",
            "",
            "Below 3 frames: the same formula without the rule, at n = 2, over the filters, figures and kinds: "
            + (f"worst coverage {min(r['coverage_without_rule'] for r in two):.3f} "
               f"({sum(r['coverage_without_rule'] < 0.93 for r in two)} of {len(two)} cells below 0.93), mean width "
               f"{np.nanmean([r['width_without_rule'] for r in two]):.3f}" if two else "—")
            + " — it fails or says nothing, so zcut prints none.",
            "",
            "At 3 frames and more the rule withholds an interval only where every frame that defines the figure "
            "has the same value (e.g. no false positive in any of the frames: precision 1). There the formula "
            "would print a zero-width interval; how often that would have held the population's figure:",
            "",
            "| kind | filter | figure | n | samples withheld | their coverage without the rule |",
            "|---|---|---|---|---|---|",
            *(f"| {r['kind']} | {r['method']} | {r['stat']} | {r['n']} | {_percent(r['withheld'])} "
              f"| {r['withheld_coverage']:.3f} |" for r in some),
            "",
        ]
    lines += [
        f"## zcut's interval ({CHOSEN}) against the former percentile bootstrap, every cell",
        "",
        "| kind | filter | figure | n | population figure | coverage | no interval | mean width "
        "| bootstrap coverage | bootstrap mean width |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in chosen:
        b = by.get((BASELINE, r["kind"], r["method"], r["stat"], r["n"]))
        flag = " ✗" if r["coverage"] < 0.93 else ""
        lines.append(f"| {r['kind']} | {r['method']} | {r['stat']} | {r['n']} | {r['truth']:.3f} "
                     f"| {r['coverage']:.3f}{flag} | {r['none']:.3f} | {r['width']:.3f} "
                     + (f"| {b['coverage']:.3f} | {b['width']:.3f} |" if b else "| — | — |"))
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ 4. a parametric model
def fit_model(t: np.ndarray, f: np.ndarray, fn: np.ndarray) -> dict[str, float]:
    """A small parametric model of one filter's per-frame counts (the test suite's population):
    true outlier pixels L = TP + FN lognormal; recall per frame Beta (moments); FP zero with
    probability ``p0``, else lognormal with the median and the 90th percentile of the non-zero FP
    (the upper tail, which moves a pooled ratio, matched rather than the mean of log FP)."""
    L = (t + fn).astype(np.float64)
    rec = t / np.maximum(L, 1)
    m, v = rec.mean(), rec.var()
    k = max(m * (1 - m) / max(v, 1e-12) - 1, 1e-3)
    nz = f[f > 0].astype(np.float64)
    return {"L_mu": float(np.log(L).mean()), "L_sigma": float(np.log(L).std()), "recall_a": float(m * k),
            "recall_b": float((1 - m) * k), "fp_p0": float(np.mean(f == 0)),
            "fp_mu": float(np.log(np.median(nz))),
            "fp_sigma": float((np.log(np.percentile(nz, 90)) - np.log(np.median(nz))) / 1.2815515655446004)}


def fit(args) -> int:
    work = Path(args.work)
    for kind in args.kinds.split(","):
        pop = load_counts(work, kind, args.set, args.size)
        for m in METHODS:
            p = fit_model(*pop[m])
            print(f'("{kind}", "{m}"): ' + "{" + ", ".join(f'"{k}": {v:.3g}' for k, v in p.items()) + "},")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate")
    g.add_argument("--kinds", default="zinc_nuts,black_nuts")
    g.add_argument("--sets", default="tune,heldout")
    g.add_argument("--frames", type=int, default=160)
    g.add_argument("--frames-per-log", type=int, default=8)
    g.add_argument("--size", default="1920x1200")
    g.add_argument("--workers", type=int, default=2)
    g.add_argument("--work", default="/tmp/zcut_interval_coverage")
    s = sub.add_parser("simulate")
    s.add_argument("--kinds", default="zinc_nuts,black_nuts")
    s.add_argument("--set", default="tune")
    s.add_argument("--size", default="1920x1200")
    s.add_argument("--draws", type=int, default=4000)
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--without-replacement", action="store_true")
    s.add_argument("--candidates", default="", help="names separated by ; (default: every one)")
    s.add_argument("--markdown", help="write the Markdown tables here (docs/coverage.md)")
    s.add_argument("--note", help="a sentence for the Markdown's \"How it was measured\" (e.g. which zcut counted the sets)")
    s.add_argument("--work", default="/tmp/zcut_interval_coverage")
    f = sub.add_parser("fit", help="print the parametric model of each population (the tests' populations)")
    f.add_argument("--kinds", default="zinc_nuts,black_nuts")
    f.add_argument("--set", default="tune")
    f.add_argument("--size", default="1920x1200")
    f.add_argument("--work", default="/tmp/zcut_interval_coverage")
    args = ap.parse_args()
    return {"generate": generate, "simulate": simulate, "fit": fit}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
