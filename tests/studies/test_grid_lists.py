"""The sweep's LIST parser at scale (issue 35 item 4): values merged in O(n log n) with the same result
as the quadratic original (kept here as the reference), and a list longer than --max-points refused
before it is expanded."""

from __future__ import annotations

import time

import numpy as np
from cli_helpers import run_cli

from studies.grid import REL_TOL, _tidy, merge_values, parse_list


def reference_merge_values(*groups):
    """The original merge: each value against every value kept before it (quadratic)."""
    kept: list[float] = []
    for group in groups:
        for v in group:
            if not any(abs(v - k) <= REL_TOL * max(1.0, abs(v), abs(k)) for k in kept):
                kept.append(v)
    return tuple(sorted(kept))


def _lists():
    rng = np.random.default_rng(35)
    yield [0.105, 0.10500000000000001, 0.1050000000000001, 0.035]
    yield [1.0, 1.0000001, 1.0 + 5e-10, 1.0 - 5e-10, 1.0 + 1.5e-9, 1.0 + 2.5e-9, 1.0 + 0.9e-9]
    yield [0.0, -0.0, 1e-10, -1e-10, 2e-9, -2e-9, 5e-10]
    yield [1e6, 1e6 * (1 + REL_TOL / 2), 1e6 * (1 + 2 * REL_TOL), -1e6, -1e6 * (1 + REL_TOL / 2)]
    yield [_tidy(0.1 + 0.4 * i / 999) for i in range(1000)]
    yield [_tidy(v) for v in rng.uniform(0, 1, 3000)]
    # chains of values each within the tolerance of the next, in every order: the order decides
    chain = [1.0 + i * 0.6e-9 for i in range(40)]
    yield chain
    yield chain[::-1]
    yield list(rng.permutation(chain))
    big = [1e6 * (1 + i * 0.6 * REL_TOL) for i in range(60)]
    yield list(rng.permutation(big + [-v for v in big] + chain))
    # many near-duplicates around a few centres, shuffled
    centres = rng.uniform(-5, 5, 20)
    yield list(rng.permutation(np.concatenate([c + rng.normal(0, 3e-9, 100) for c in centres])))
    yield list(rng.permutation(np.repeat(rng.uniform(0, 2, 200), 7)))


def test_merge_values_equals_the_quadratic_original():
    for values in _lists():
        values = [float(v) for v in values]
        assert merge_values(values) == reference_merge_values(values)
        half = len(values) // 2
        assert merge_values(values[:half], values[half:]) == reference_merge_values(values[:half], values[half:])
        assert merge_values(values[half:], values[:half]) == reference_merge_values(values[half:], values[:half])


def test_parse_list_equals_the_original_on_ranges():
    for text in ("0.1:0.5:1000", "0.035:0.105:3", "0:1e-8:50", "1:1:1", "-3:3:2001", "0.2:0.2000000001:300"):
        start, stop, count = (float(x) for x in text.split(":"))
        count = int(count)
        values = [start + (stop - start) * i / (count - 1) for i in range(count)] if count > 1 else [start]
        assert parse_list(text, name="x") == reference_merge_values(_tidy(v) for v in values), text


def test_a_million_values_are_refused_before_they_are_expanded(tmp_path, capsys):
    """`--step 0.1:0.5:1000000` once spent minutes in the parser before the --max-points guard."""
    t0 = time.process_time()
    rc, out, err = run_cli(capsys, "sweep", tmp_path / "none.mcap", "-o", tmp_path / "s", "--step", "0.1:0.5:1000000")
    assert rc == 1 and err.strip().splitlines()[-1] == "error: --step has 1000000 values (more than --max-points 5000): " \
                                      "narrow it, or use --force", err
    rc, _, err = run_cli(capsys, "sweep", tmp_path / "none.mcap", "-o", tmp_path / "s",
                         "--rho", ",".join(["0.5"] * 6000))
    assert rc == 1 and "--rho has 6000 values (more than --max-points 5000)" in err
    # with --force the list is expanded, in O(n log n)
    values = parse_list("0.1:0.5:1000000", name="--step")
    assert values is not None and len(values) == 1000000 and values[0] == 0.1 and values[-1] == 0.5
    print(f"refused and parsed 10^6 values in {time.process_time() - t0:.2f} CPU-s")
