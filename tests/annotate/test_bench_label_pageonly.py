"""bench/bench_label_pageonly.py's --compare: two --diagnose runs as one cause table, before -> after; and its
other --diagnose helpers (the seeds, --config, the missed truth's causes, --fits-cache)."""

from __future__ import annotations

from collections.abc import Iterator
from types import ModuleType

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("bench_label_pageonly.py")


def _row(bench: ModuleType, log: str, *, iou: float, causes: tuple[int, int, int, int], cpu: float) -> dict:
    row = {"log": log, "frame": 0, "fits": 300, "iou": iou, "label": 2 * sum(causes) + 10, "label_truth": sum(causes) + 10,
           "non_truth": sum(causes), "parts_unfitted_seen": 7, bench.MISSED_IN_FITS: 5, "cpu_fits": cpu}
    row.update(zip(bench.CAUSES, causes))
    return row


def test_compare_prints_before_arrow_after_and_the_largest_cause(bench):
    before = [_row(bench, "a.mcap", iou=0.452, causes=(7475, 1954, 1301, 464), cpu=9.5),
              _row(bench, "b.mcap", iou=0.739, causes=(808, 59, 1401, 22), cpu=7.4)]
    after = [_row(bench, "b.mcap", iou=0.739, causes=(808, 59, 1401, 22), cpu=7.4),
             _row(bench, "a.mcap", iou=0.455, causes=(7667, 1917, 1299, 631), cpu=10.4)]
    lines = bench.compare(before, after)
    assert lines[0].startswith("| log | frame | fits | IoU paper |") and lines[1].count("|") == lines[0].count("|")
    a = next(v for v in lines if v.startswith("| a.mcap | 0 |"))  # matched by log and frame, not by order
    assert "| 0.452 → 0.455 |" in a and "| 7,475 → 7,667 (7 → 7) |" in a and "| 464 → 631 |" in a and "| 9.5 → 10.4 |" in a
    assert a.count("|") == lines[0].count("|")
    assert "  a.mcap frame 0: unfitted instances, 7,667 of 11,514 px not truth (67%)" in lines
    assert "  b.mcap frame 0: Err < truth's, 1,401 of 2,290 px not truth (61%)" in lines


def test_compare_refuses_a_frame_missing_before(bench):
    with pytest.raises(SystemExit, match="c.mcap frame 0 is not in the before file"):
        bench.compare([], [_row(bench, "c.mcap", iou=0.5, causes=(1, 2, 3, 4), cpu=1.0)])


def test_below_around_flags_a_patch_with_something_lower_beside_it(bench):
    """--ring-below's cue: a proposal has a valid neighbour (not its own) more than 2 mm farther from the camera than
    its median depth; invalid neighbours and its own pixels never count."""
    import numpy as np

    z = np.full((6, 8), 500.0)
    ids = np.zeros((6, 8), np.int64)
    ids[1:3, 1:3] = 1  # a patch level with all around it
    ids[1:3, 5:7] = 2  # a patch with one pixel beside it 2.5 mm farther
    z[3, 7] = 502.5
    ids[4, 0] = 3  # a single pixel whose only pixel far below is invalid
    valid = np.ones((6, 8), bool)
    valid[5, 0] = False
    z[5, 0] = 900.0
    got = bench.below_around(ids, 3, z, valid)
    assert got.tolist() == [False, False, True, False]
    z[1, 1] = 497.0  # the patch's own pixels never count, whatever their depth
    assert bench.below_around(ids, 3, z, valid).tolist() == [False, False, True, False]
    assert bench.below_around(np.zeros((2, 2), np.int64), 0, np.zeros((2, 2)), np.ones((2, 2), bool)).tolist() == [False]
    z[0, 0] = 502.1  # exactly beyond 2 mm beside proposal 1 (median 500)
    assert bench.below_around(ids, 3, z, valid).tolist() == [False, True, True, False]


def _list(rows: list[tuple[int, float, float, float, int]]) -> dict:
    """A proposal list as bench.proposals_of gives it: (n, cx, cy, dist_mm, fit) per row."""
    import numpy as np

    n, cx, cy, dist, fit = (np.array(c, np.float64) for c in zip(*rows))
    return {"id": np.arange(1, len(rows) + 1, dtype=np.float64), "n": n, "cx": cx, "cy": cy, "dist_mm": dist, "fit": fit}


def test_next_seed_takes_the_largest_at_its_centre_pixel_once(bench):
    """--seed-px's choice: the largest proposal of at least N px, clicked at the pixel holding its centre (floor),
    never a pixel clicked before, never a rejected fit's pixels; None when none is left."""
    nan = float("nan")
    col = _list([(40, 10.9, 3.2, 5.0, -1), (700, 100.5, 50.99, 2.0, -1), (900, 7.0, 8.0, nan, 3), (120, 0.2, 0.7, 9.0, -1)])
    assert bench.next_seed(col, [], 30) == (100, 50, 700)  # the rejected fit's 900 px are no candidate
    assert bench.next_seed(col, [(100, 50)], 30) == (0, 0, 120)
    assert bench.next_seed(col, [(100, 50), (0, 0)], 30) == (10, 3, 40)
    assert bench.next_seed(col, [(100, 50), (0, 0)], 41) is None  # below N
    assert bench.next_seed(col, [(100, 50), (0, 0), (10, 3)], 1) is None
    assert bench.next_seed({k: v[:0] for k, v in col.items()}, [], 1) is None  # an empty list


def test_next_seed_breaks_ties_as_the_page_lists_proposals(bench):
    """Among equal sizes the first in the list: the page lists proposals farthest first (one with no distance first
    of all), then by row, then by column of their centres."""
    nan = float("nan")
    col = _list([(50, 1.0, 1.0, 3.0, -1), (50, 9.0, 2.0, 8.0, -1), (50, 3.0, 2.0, 8.0, -1), (50, 4.0, 4.0, nan, -1),
                 (50, 5.0, 0.5, 8.0, -1)])
    got = []
    while (s := bench.next_seed(col, [p[:2] for p in got], 50)) is not None:
        got.append(s)
    assert [p[:2] for p in got] == [(4, 4), (5, 0), (3, 2), (9, 2), (1, 1)]


class _Fits:
    """A stand-in for annotate.fits.FrameFits in seed_steps: its proposals (n, cx, cy), and which centre pixels a
    click finds an instance at (that proposal leaves; a click that finds nothing returns the same object)."""

    def __init__(self, props: list[tuple[int, float, float]], finds: set[tuple[int, int]]) -> None:
        self.props, self.finds, self.fits = props, finds, ()

    def seeded(self, x: int, y: int, xyz_mm, config) -> _Fits:
        if (x, y) not in self.finds:
            return self
        return _Fits([p for p in self.props if (int(p[1]), int(p[2])) != (x, y)], self.finds)


def test_seed_steps_clicks_largest_first_reads_again_after_a_find_and_a_larger_n_is_a_prefix(bench, monkeypatch):
    reads = []

    def proposals_of(ff, xyz_mm, heights, valid, rejected):
        reads.append(len(ff.props))
        return _list([(n, cx, cy, 1.0, -1) for n, cx, cy in ff.props]), None

    monkeypatch.setattr(bench, "proposals_of", proposals_of)
    ff = _Fits([(50, 1.5, 1.5), (900, 7.2, 3.9), (300, 4.0, 4.0), (20, 9.0, 9.0)], finds={(7, 3), (1, 1)})
    steps = list(bench.seed_steps(ff, None, None, None, None, 30))
    assert [s.clicked for s in steps] == [(), ((7, 3),), ((7, 3), (4, 4)), ((7, 3), (4, 4), (1, 1))]
    assert [s.found for s in steps] == [0, 1, 1, 2] and [s.next_px for s in steps] == [900, 300, 50, 0]
    assert reads == [4, 3, 2]  # the list is read once, then after each click that found an instance
    assert steps[-1].ff.props == [(300, 4.0, 4.0), (20, 9.0, 9.0)]
    big = list(bench.seed_steps(ff, None, None, None, None, 100))
    assert [s.clicked for s in big] == [s.clicked for s in steps[:3]] and big[-1].next_px == 0


def test_config_reaches_the_diagnosed_session(bench, monkeypatch, tmp_path):
    """--config: the pipeline config file --diagnose prepares the frames with (the zone's bin removal here), and
    none gives the defaults."""
    from replay.synth.log import write_synthetic_log

    log = write_synthetic_log(tmp_path / "s.mcap", kind="zinc_nuts", frames=1, seed=5, size=(120, 192))
    toml = tmp_path / "off.toml"
    toml.write_text('[removal]\nstraggler_bound = "off"\n')
    monkeypatch.setattr(bench, "CONFIG", None)
    assert bench.pipeline_options().open_session(log).config.removal.straggler_bound == "below_rim"
    monkeypatch.setattr(bench, "CONFIG", toml)
    opts = bench.pipeline_options()
    assert opts.methods == "zcut,explained" and opts.config == str(toml)
    assert opts.open_session(log).config.removal.straggler_bound == "off"


@pytest.mark.parametrize(("argv", "match"), [
    (["--config", "X.toml", "--logs", "a.mcap"], "--config is a --diagnose option"),
    (["--config", "/nonexistent/x.toml", "--diagnose", "a.mcap"], "--config: /nonexistent/x.toml: no such file"),
])
def test_config_refused(bench, monkeypatch, argv, match):
    monkeypatch.setattr("sys.argv", ["bench_label_pageonly.py", *argv])
    with pytest.raises(SystemExit, match=match):
        bench.main()


def test_missed_causes_gives_each_missed_truth_pixel_one_cause(bench):
    """A 1 x 12 frame: fit 0's band is half truth (a displaced patch), fit 1's is not; the missed truth pixels in fit
    1's band are split by their true distance against k x the page's Err and by the instance the fit stands for."""
    from types import SimpleNamespace

    import numpy as np

    H, W = 1, 12
    ff = SimpleNamespace(fits=[{}, {}], fit_pix=np.array([0, 1, 2, 3, 4, 5, 6, 7, 10, 11]),
                         fit_of=np.array([0, 0, 1, 1, 1, 1, 1, 1, 1, 1]),
                         un_pix=np.array([9]), part_err_mm=(0.1, 0.1), f_px=1000.0, floor_mm=0.0, k=3.0)
    truth = np.array([[1, 0, 1, 1, 1, 0, 0, 0, 1, 1, 0, 0]], bool)  # fit 1's band: 3 of 8 truth
    miss = truth.copy()
    fitpix = np.zeros((H, W), bool)
    fitpix.ravel()[ff.fit_pix] = True
    xyz = np.zeros((H, W, 3))
    xyz[..., 2] = 100.0  # footprint 0.1 mm: Err = sqrt(0.01 + 0.005) = 0.1225 mm, k x Err = 0.367 mm
    tdist = np.array([[5.0, 0, 0.2, 1.0, 1.0, 0, 0, 0, 0, 5.0, 0, 0]])
    tcode = np.array([[0, 0, 1, 1, 2, 1, 1, 1, -3, 2, 1, 1]])  # pixel 4 lies on instance 2, which no fit stands for
    match_of = np.array([0, 1, -1])
    got = bench.missed_causes(ff, miss, truth, fitpix, tcode, tdist, match_of, xyz, np.zeros((H, W), np.int64))
    assert got == {"missed: displaced patch": 1, "missed: Err above": 1, "missed: misposed": 1,
                   "missed: other instance": 1, "missed: bin or table": 1, "missed: other": 1, "missed": 6}
    assert sum(got[k] for k in bench.MISSED) == got["missed"]


def _fake_fitting(bench, monkeypatch, n_frames=2, summary=True):
    """The session and fit_frame :func:`fitted_frames` calls, replaced by fakes that count: sessions opened, frames
    fitted, frames the pipeline ran (a log of ``n_frames``; ``summary``: whether its reader knows how many)."""
    from types import SimpleNamespace

    import annotate.fits as af

    calls = {"open": 0, "fit": 0, "ran": []}

    class Session:
        config = "cfg"
        prepared = None
        reader = SimpleNamespace(n_frames=n_frames if summary else None)

        def results(self, frames=(0, None)):
            start, stop = frames
            for i in range(start, n_frames if stop is None else min(stop, n_frames)):
                calls["ran"].append(i)
                yield SimpleNamespace(index=i), {"frame": i}

    def open_session(log):
        calls["open"] += 1
        return Session()

    def fit_frame(frame, job, config, model):
        calls["fit"] += 1
        return {"fits of": frame.index, "job": job}

    monkeypatch.setattr(bench, "pipeline_options", lambda: SimpleNamespace(open_session=open_session))
    monkeypatch.setattr(af, "fit_frame", fit_frame)
    monkeypatch.setattr(af.Job, "of", staticmethod(lambda r: r))
    return calls


def test_fits_cache_fits_once_and_reads_back_the_same(bench, monkeypatch, tmp_path):
    """--fits-cache DIR: the first run fits every frame (and pickles frame, job, fits, CPU-s), the next ones read them
    back without opening a session; the same name with other bytes is fitted anew."""
    calls = _fake_fitting(bench, monkeypatch)
    monkeypatch.setattr(bench, "FITS_CACHE", tmp_path / "cache")
    log = tmp_path / "a.mcap"
    log.write_bytes(b"x" * 10)
    first = [(f.index, j, ff, c) for f, j, ff, _, c in bench.fitted_frames(log)]
    assert (calls["open"], calls["fit"]) == (1, 2) and [c for *_, c in first] == ["cfg", "cfg"]
    again = list(bench.fitted_frames(log))
    assert (calls["open"], calls["fit"]) == (1, 2)  # read back: no session, no fit
    assert [(f.index, j, ff) for f, j, ff, _, _ in again] == [t[:3] for t in first]
    assert [c for *_, c in again] == [None, None] and [cpu for *_, cpu, _ in again] == [cpu for *_, cpu, _ in
                                                                                        bench.fitted_frames(log)]
    log.write_bytes(b"y" * 10)  # other bytes, the same size: fitted anew
    list(bench.fitted_frames(log))
    assert (calls["open"], calls["fit"]) == (2, 4)
    monkeypatch.setattr(bench, "FITS_CACHE", None)  # no cache: fitted on every run
    list(bench.fitted_frames(log))
    list(bench.fitted_frames(log))
    assert (calls["open"], calls["fit"]) == (4, 8)


def test_fits_cache_fits_only_the_frames_asked_and_missing(bench, monkeypatch, tmp_path):
    """``frames``: only those frames are run and fitted; a later run over more frames, or over every frame, fits only
    the ones the cache lacks (it was all-or-nothing: a cache of some frames hid the others) and yields every frame in
    log order; a log without a summary runs every frame once and fits only the missing ones."""
    calls = _fake_fitting(bench, monkeypatch, n_frames=5)
    monkeypatch.setattr(bench, "FITS_CACHE", tmp_path / "cache")
    log = tmp_path / "a.mcap"
    log.write_bytes(b"x" * 10)
    got = [f.index for f, *_ in bench.fitted_frames(log, [3, 1])]
    assert got == [1, 3] and calls["fit"] == 2 and calls["ran"] == [1, 3]
    got = [(f.index, c) for f, _, _, _, c in bench.fitted_frames(log, [1, 2, 3, 4])]
    assert got == [(1, None), (2, "cfg"), (3, None), (4, "cfg")]
    assert calls["fit"] == 4 and calls["ran"] == [1, 3, 2, 4]
    got = [f.index for f, *_ in bench.fitted_frames(log)]  # every frame: only frame 0 is missing
    assert got == [0, 1, 2, 3, 4] and calls["fit"] == 5 and calls["ran"][4:] == [0] and calls["open"] == 3
    assert [f.index for f, *_ in bench.fitted_frames(log)] == [0, 1, 2, 3, 4] and calls["open"] == 3  # no session
    assert [f.index for f, *_ in bench.fitted_frames(log, [])] == [] and calls["open"] == 3

    calls = _fake_fitting(bench, monkeypatch, n_frames=3, summary=False)
    monkeypatch.setattr(bench, "FITS_CACHE", tmp_path / "cache2")
    assert [f.index for f, *_ in bench.fitted_frames(log, [2])] == [2]
    assert [f.index for f, *_ in bench.fitted_frames(log)] == [0, 1, 2]
    assert calls["fit"] == 3 and calls["ran"] == [2, 0, 1, 2]


def test_diag_frames_reads_the_frames_argument(bench, monkeypatch, tmp_path):
    """The diagnostics' shared arguments: ``--frames`` fits only those frames; a bad list is one line."""
    calls = _fake_fitting(bench, monkeypatch, n_frames=4)
    monkeypatch.setattr(bench, "FITS_CACHE", None)  # restored after: diag_frames sets it from the arguments
    log = tmp_path / "a.mcap"
    log.write_bytes(b"x" * 10)
    ap = bench.diag_arguments("d")
    args = ap.parse_args([str(log), "--frames", "2,0", "--fits-cache", str(tmp_path / "c")])
    assert [f.index for f, _, _ in bench.diag_frames(args)] == [0, 2] and calls["fit"] == 2
    args = ap.parse_args([str(log), "--frames", "two"])
    with pytest.raises(SystemExit, match="--frames: comma-separated frame indices, not 'two'"):
        list(bench.diag_frames(args))


@pytest.mark.parametrize("argv", [["--fits-cache", "D", "--logs", "a.mcap"],
                                  ["--fits-cache", "D", "--diagnose", "a.mcap", "--seed-px", "50"]])
def test_fits_cache_refused(bench, monkeypatch, argv):
    monkeypatch.setattr("sys.argv", ["bench_label_pageonly.py", *argv])
    with pytest.raises(SystemExit, match="--fits-cache is a --diagnose option"):
        bench.main()
