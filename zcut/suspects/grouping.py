"""Grouping the suspects of one frame for review: per detector and strength class, by proximity, within
``SuspectParams.max_groups`` groups (:func:`group_suspects`; the page's share of the budget beside it is
:mod:`annotate.budget`).
"""

from __future__ import annotations

import numba
import numpy as np
from scipy import ndimage

from ..components import find_root, union_roots
from ..params import SuspectParams
from .detectors import DETECTORS, label_gather

# grouping: a detector with more components than this is pre-merged with a larger radius first
MAX_NODES = 1500
# grouping: the bounds of a suspect's strength classes, in |gap| / τ (the median over its component):
# at the noise's edge (below 2 τ), clearly off the surface, far off it (8 τ and more). Suspects of
# different classes are not grouped together while the frame's group budget allows it.
STRENGTH_CLASSES = (2.0, 8.0)


def _components(m: np.ndarray, r: int) -> tuple[np.ndarray, int]:
    """8-connected components of ``m`` grown by ``r`` pixels (labels on ``m``'s pixels only, 1..n)."""
    grown = ndimage.maximum_filter(m.view(np.uint8), size=2 * r + 1, mode="constant") > 0 if r > 0 else m
    lab, n = ndimage.label(grown, structure=np.ones((3, 3), bool))
    lab = np.where(m, lab, 0)
    used = np.unique(lab[m])
    remap = np.zeros(n + 1, np.int32)
    remap[used] = np.arange(1, used.size + 1, dtype=np.int32)
    return remap[lab], int(used.size)


# the sparse components of a kind are found by linking its pixels directly up to this radius; beyond,
# by growing a cropped mask (_components) as before
SPARSE_MAX_RADIUS = 16


@numba.njit(cache=True)
def _sparse_components(flat, W, r):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_components` of the pixels ``flat`` (raster order, one kind) without growing a mask.

    Two pixels are in one component of the grown mask when a chain of them joins them, each within
    Chebyshev distance 2r + 1 of the next (their grown squares touch or overlap); ``ndimage.label``
    numbers the components by their first grown pixel in raster order: row max(top - r, 0), column
    max(c - r, 0) for c the leftmost column among the pixels whose square reaches that row.
    The pixels are joined run by run (the union-find of :mod:`zcut.components`: a component's root is its
    first run). Returns the label (1..n) of each pixel, n and the (n, 4) bounding boxes (row0, col0, row1,
    col1; ends exclusive) of the labels' pixels.
    """
    m = flat.size
    reach = 2 * r + 1
    rows = np.empty(m, np.int64)  # the pixels' rows and columns, one division each
    cols = np.empty(m, np.int64)
    for k in range(m):
        i = flat[k] // W
        rows[k] = i
        cols[k] = flat[k] - i * W
    # runs: the pixels of a row each within ``reach`` columns of the previous one (one component). Two
    # runs at most ``reach`` rows apart touch when their column spans are within ``reach``: a pixel of one
    # then lies in the other's span or at its end, within reach / 2 of the other's pixels
    run_of = np.empty(m, np.int64)
    first = np.empty(m, np.int64)  # per run: its first pixel, row, first and last columns
    run_row = np.empty(m, np.int64)
    c0 = np.empty(m, np.int64)
    c1 = np.empty(m, np.int64)
    nr = 0
    for k in range(m):
        if k > 0 and rows[k - 1] == rows[k] and cols[k] - cols[k - 1] <= reach:
            c1[nr - 1] = cols[k]
        else:
            first[nr] = k
            run_row[nr] = rows[k]
            c0[nr] = cols[k]
            c1[nr] = cols[k]
            nr += 1
        run_of[k] = nr - 1
    H = rows[m - 1] + 1 if m else 0
    start = np.zeros(H, np.int64)  # each row's runs: start .. end - 1 (none: 0 .. -1)
    end = np.zeros(H, np.int64)
    for q in range(nr):
        if q == 0 or run_row[q] != run_row[q - 1]:
            start[run_row[q]] = q
        end[run_row[q]] = q + 1
    parent = np.arange(nr)
    at = np.empty(reach + 1, np.int64)  # per row above: the first run not left of the current run's reach
    row = -1
    for q in range(nr):
        i = run_row[q]
        if i != row:  # a new row: its runs come left to right, so each row above is read once from its start
            row = i
            for d in range(1, min(reach, i) + 1):
                at[d] = start[i - d]
        lo = c0[q] - reach
        hi = c1[q] + reach
        for d in range(1, min(reach, i) + 1):
            p = at[d]
            e = end[i - d]
            while p < e and c1[p] < lo:
                p += 1
            at[d] = p
            while p < e and c0[p] <= hi:
                union_roots(parent, q, p)
                p += 1
    root = np.empty(nr, np.int64)  # per run: its component's root run, the first in raster order
    for q in range(nr):
        root[q] = find_root(parent, q)
    # the root run's row is the component's top one; the leftmost column of the rows the grown first row
    # reaches (r0 .. r0 + r) is the least first column of their runs
    left = np.full(nr, np.iinfo(np.int64).max)
    for q in range(nr):
        x = root[q]
        r0 = max(run_row[x] - r, 0)
        if run_row[q] <= r0 + r:
            left[x] = min(left[x], c0[q])
    roots = np.empty(nr, np.int64)
    n = 0
    for q in range(nr):
        if root[q] == q:
            roots[n] = q
            n += 1
    roots = roots[:n]
    key = np.empty(n, np.int64)
    for g in range(n):
        x = roots[g]
        key[g] = max(run_row[x] - r, 0) * (W + 1) + max(left[x] - r, 0)
    order = np.argsort(key)
    rank = np.empty(nr, np.int64)
    for g in range(n):
        rank[roots[order[g]]] = g + 1
    boxes = np.empty((n, 4), np.int64)
    boxes[:, 0] = np.iinfo(np.int64).max
    boxes[:, 1] = np.iinfo(np.int64).max
    boxes[:, 2] = -1
    boxes[:, 3] = -1
    for q in range(nr):
        g = rank[root[q]]
        rank[q] = g  # a run's label (its root's rank is set first: the root comes first)
        i = run_row[q]
        boxes[g - 1, 0] = min(boxes[g - 1, 0], i)
        boxes[g - 1, 1] = min(boxes[g - 1, 1], c0[q])
        boxes[g - 1, 2] = max(boxes[g - 1, 2], i + 1)
        boxes[g - 1, 3] = max(boxes[g - 1, 3], c1[q] + 1)
    labels = np.empty(m, np.int64)
    for k in range(m):
        labels[k] = rank[run_of[k]]
    return labels, n, boxes


def _kind_components(flat: np.ndarray, shape: tuple[int, int], r: int) -> tuple[np.ndarray, int, np.ndarray]:
    """Labels (1..n, per pixel of ``flat``), n and bounding boxes of :func:`_components` of the
    pixels ``flat`` (flat indices in raster order)."""
    if flat.size == 0:
        return np.zeros(0, np.int64), 0, np.zeros((0, 4), np.int64)
    if r <= SPARSE_MAX_RADIUS:
        labels, n, boxes = _sparse_components(flat, shape[1], r)
        return labels, int(n), boxes
    rows, cols = np.divmod(flat, shape[1])
    r0, r1 = max(int(rows.min()) - r, 0), min(int(rows.max()) + r + 1, shape[0])
    c0, c1 = max(int(cols.min()) - r, 0), min(int(cols.max()) + r + 1, shape[1])
    m = np.zeros((r1 - r0, c1 - c0), bool)  # the crop that holds the grown mask
    m[rows - r0, cols - c0] = True
    lab, n = _components(m, r)
    boxes = np.array([[s[0].start + r0, s[1].start + c0, s[0].stop + r0, s[1].stop + c0]
                      for s in ndimage.find_objects(lab, max_label=n)], np.int64).reshape(-1, 4)
    return lab[rows - r0, cols - c0].astype(np.int64), n, boxes


# the merge keeps, per box, its NEAR nearest boxes of its kind (by united diagonal, then index) as they were
# when last listed: refreshing a box whose partner merged reads that list, not the whole kind
NEAR = 8
# the squared diagonal of a dead box with any other (a living pair's is smaller)
FAR = np.int64(1) << 61


@numba.njit(cache=True)
def _merge_kernel(boxes, kind, max_groups, near):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_merge_compact` (see there) with ``near`` listed neighbours a box.

    Distances are compared as squared integer diagonals, whose order is the order of their square roots
    (the reference's ``np.hypot``), and each box only with the boxes of its kind; a box's partner is its
    nearest one, the lowest index on ties (``np.argmin`` of its row), and the merge taken is the pair of
    the box with the smallest (distance, index) (``np.argmin`` of the partners' distances).

    Why the lists give the same partners as a scan of the kind: a box only grows (when it takes in its
    partner) or dies, so the distance between two living boxes never decreases. A box's list holds the
    ``near`` smallest keys (distance, index) of its kind's other living boxes when it was listed, and
    ``lim`` the largest of them: every box left out had a larger key then, and has one still. So when
    the smallest current key on the list is at most ``lim`` it is the smallest of the kind; otherwise
    (or when every listed box died) the box is listed again from a scan of its kind. A list that held
    every other box of the kind needs no bound. The merged box is listed afresh (all its distances
    changed); a box whose partner was neither of the pair keeps it: its other distances only grew or
    went, so the reference's update of the rows against the merged box never changes a partner.
    The next pair is the root of a tournament tree over (distance, index); the groups are followed to
    their representative through the merges (each merge joins the higher index into the lower).
    """
    n = boxes.shape[0]
    inf = np.iinfo(np.int64).max
    best = np.full(n, inf)
    partner = np.zeros(n, np.int64)  # a box with no partner: 0, as np.argmin of a row of inf
    alive = np.ones(n, np.bool_)
    joined = np.arange(n)  # the box each merged box went into
    r0 = boxes[:, 0].copy()
    c0 = boxes[:, 1].copy()
    r1 = boxes[:, 2].copy()
    c1 = boxes[:, 3].copy()
    by_kind = np.argsort(kind, kind="mergesort")  # each kind's boxes in increasing index
    start = np.zeros(n, np.int64)  # of each box's kind in by_kind
    stop = np.zeros(n, np.int64)
    s = 0
    while s < n:
        e = s
        while e < n and kind[by_kind[e]] == kind[by_kind[s]]:
            e += 1
        for q in range(s, e):
            start[by_kind[q]] = s
            stop[by_kind[q]] = e
        s = e
    near = max(near, 1)
    listed = np.empty((n, near), np.int64)  # each box's listed neighbours, by key when listed
    listed_d = np.empty((n, near), np.int64)
    n_listed = np.zeros(n, np.int64)
    whole = np.zeros(n, np.bool_)  # the list held every other living box of the kind
    lim_d = np.zeros(n, np.int64)  # the largest key listed
    lim_k = np.zeros(n, np.int64)

    # the boxes again in by_kind's order, for list_anew's scan in vector lanes; a dead box's is FAR's
    # (coordinates of pixels are far inside +-2^29, so a living pair's squared diagonal is below 2^61)
    far = np.int64(1) << 29
    pos = np.empty(n, np.int64)
    for q in range(n):
        pos[by_kind[q]] = q
    kr0 = r0[by_kind]
    kc0 = c0[by_kind]
    kr1 = r1[by_kind]
    kc1 = c1[by_kind]
    dist = np.empty(n, np.int64)

    def settle(i, m, is_whole):  # type: ignore[no-untyped-def]
        """Box i's list of m: whether it holds every box of its kind, its best partner and the list's last key."""
        n_listed[i] = m
        whole[i] = is_whole
        if m > 0:
            best[i] = listed_d[i, 0]
            partner[i] = listed[i, 0]
            lim_d[i] = listed_d[i, m - 1]
            lim_k[i] = listed[i, m - 1]
        else:
            best[i] = inf
            partner[i] = 0

    def list_anew(i):  # type: ignore[no-untyped-def]
        s0 = start[i]
        s1 = stop[i]
        a0 = r0[i]
        b0 = c0[i]
        a1 = r1[i]
        b1 = c1[i]
        for q in range(s0, s1):
            dr = max(kr1[q], a1) - min(kr0[q], a0)
            dc = max(kc1[q], b1) - min(kc0[q], b0)
            dist[q] = dr * dr + dc * dc
        dist[pos[i]] = FAR
        m = 0
        seen = 0
        bar = FAR  # a box enters the list below it: any living one while the list is short
        for q in range(s0, s1):
            d = dist[q]
            if d >= FAR:
                continue  # i itself, or dead
            seen += 1
            if d >= bar:
                continue  # not below the last listed key (its index is larger: a larger key on ties)
            if m == near:
                p = m - 1
            else:
                p = m
                m += 1
            while p > 0 and listed_d[i, p - 1] > d:
                listed_d[i, p] = listed_d[i, p - 1]
                listed[i, p] = listed[i, p - 1]
                p -= 1
            listed_d[i, p] = d
            listed[i, p] = by_kind[q]
            if m == near:
                bar = listed_d[i, m - 1]
        settle(i, m, seen <= near)  # type: ignore[no-untyped-call]  # numba closure

    def refresh(i):  # type: ignore[no-untyped-def]
        b = inf
        bj = 0
        found = False
        for t in range(n_listed[i]):
            k = listed[i, t]
            if not alive[k]:
                continue
            dr = max(r1[k], r1[i]) - min(r0[k], r0[i])
            dc = max(c1[k], c1[i]) - min(c0[k], c0[i])
            d = dr * dr + dc * dc
            if not found or d < b or (d == b and k < bj):
                b = d
                bj = k
                found = True
        if whole[i] or (found and (b < lim_d[i] or (b == lim_d[i] and bj <= lim_k[i]))):
            best[i] = b
            partner[i] = bj
        else:
            list_anew(i)  # type: ignore[no-untyped-call]  # numba closure

    stamp = np.full(n, -1, np.int64)
    new_d = np.empty(near, np.int64)
    new_k = np.empty(near, np.int64)  # relist_merged's work

    def relist_merged(a, b):  # type: ignore[no-untyped-def]
        # a (just grown) and b (just died): a's list is the nearest of both lists, as keys now; a box on
        # neither had keys above both bounds then, and larger ones now (a contains both boxes)
        stamp[a] = b  # b marks the boxes met in this merge (b dies in it: no later merge has it)
        m = 0
        dropped = False
        whole_ab = whole[a] or whole[b]
        if lim_d[b] > lim_d[a] or (lim_d[b] == lim_d[a] and lim_k[b] > lim_k[a]):
            bound_d = lim_d[b]
            bound_k = lim_k[b]
        else:
            bound_d = lim_d[a]
            bound_k = lim_k[a]
        for src in (a, b):
            for t in range(n_listed[src]):
                k = listed[src, t]
                if not alive[k] or stamp[k] == b:
                    continue
                stamp[k] = b
                dr = max(r1[k], r1[a]) - min(r0[k], r0[a])
                dc = max(c1[k], c1[a]) - min(c0[k], c0[a])
                d = dr * dr + dc * dc
                if m == near:
                    dropped = True
                    if d > new_d[m - 1] or (d == new_d[m - 1] and k > new_k[m - 1]):
                        continue
                    p = m - 1
                else:
                    p = m
                    m += 1
                while p > 0 and (new_d[p - 1] > d or (new_d[p - 1] == d and new_k[p - 1] > k)):
                    new_d[p] = new_d[p - 1]
                    new_k[p] = new_k[p - 1]
                    p -= 1
                new_d[p] = d
                new_k[p] = k
        for t in range(m):
            listed_d[a, t] = new_d[t]
            listed[a, t] = new_k[t]
        n_listed[a] = m
        whole[a] = whole_ab and not dropped
        if whole_ab:
            bound_d = inf
            bound_k = inf
        if dropped and (new_d[m - 1] < bound_d or (new_d[m - 1] == bound_d and new_k[m - 1] < bound_k)):
            bound_d = new_d[m - 1]
            bound_k = new_k[m - 1]
        lim_d[a] = bound_d
        lim_k[a] = bound_k
        if m > 0 and (whole[a] or new_d[0] < bound_d or (new_d[0] == bound_d and new_k[0] <= bound_k)):
            best[a] = new_d[0]
            partner[a] = new_k[0]
        elif m == 0 and whole[a]:
            best[a] = inf
            partner[a] = 0
        else:
            list_anew(a)  # type: ignore[no-untyped-call]  # numba closure

    # the tournament tree: tree[1] is the box of the smallest (best, index); leaves past n hold -1
    size = 1
    while size < n:
        size *= 2
    tree = np.full(2 * size, -1, np.int64)

    def first(x, y):  # type: ignore[no-untyped-def]
        if y < 0:
            return x
        if x < 0:
            return y
        if best[y] < best[x] or (best[y] == best[x] and y < x):
            return y
        return x

    def update(i):  # type: ignore[no-untyped-def]
        v = (size + i) // 2
        while v >= 1:
            tree[v] = first(tree[2 * v], tree[2 * v + 1])  # type: ignore[no-untyped-call]  # numba closure
            v //= 2

    # the boxes whose partner is p: a list through nxt / prv from head[p]
    head = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    prv = np.full(n, -1, np.int64)
    linked = np.full(n, -1, np.int64)  # the partner each box is linked under

    def relink(k):  # type: ignore[no-untyped-def]
        p = partner[k]
        if linked[k] == p:
            return
        if linked[k] >= 0:
            if prv[k] >= 0:
                nxt[prv[k]] = nxt[k]
            else:
                head[linked[k]] = nxt[k]
            if nxt[k] >= 0:
                prv[nxt[k]] = prv[k]
        prv[k] = -1
        nxt[k] = head[p]
        if head[p] >= 0:
            prv[head[p]] = k
        head[p] = k
        linked[k] = p

    # the first lists, every box alive: each kind's boxes by top row, a box's scan going out from its place
    # both ways until the rows alone put a box's diagonal above the list's last key (r1 >= r0: the
    # united box of boxes whose top rows are g apart is at least g high); boxes with r1 < r0: a scan of
    # the kind. A box with a key equal to the last one and a lower index enters: the scan stops above it
    by_row = by_kind.copy()
    s = 0
    while s < n:
        e = stop[by_kind[s]]
        seg = by_kind[s:e]
        by_row[s:e] = seg[np.argsort(r0[seg], kind="mergesort")]
        s = e
    place = np.empty(n, np.int64)
    for q in range(n):
        place[by_row[q]] = q
    rows_bound = True
    for q in range(n):
        if r1[q] < r0[q]:
            rows_bound = False

    def list_first(i):  # type: ignore[no-untyped-def]
        s0 = start[i]
        s1 = stop[i]
        a0 = r0[i]
        b0 = c0[i]
        a1 = r1[i]
        b1 = c1[i]
        m = 0
        for step in (-1, 1):
            q = place[i] + step
            while s0 <= q < s1:
                k = by_row[q]
                q += step
                g = r0[k] - a0 if step > 0 else a0 - r0[k]
                if m == near and g * g > listed_d[i, m - 1]:
                    break
                dr = max(r1[k], a1) - min(r0[k], a0)
                dc = max(c1[k], b1) - min(c0[k], b0)
                d = dr * dr + dc * dc
                if m == near:
                    if d > listed_d[i, m - 1] or (d == listed_d[i, m - 1] and k > listed[i, m - 1]):
                        continue
                    p = m - 1
                else:
                    p = m
                    m += 1
                while p > 0 and (listed_d[i, p - 1] > d or (listed_d[i, p - 1] == d and listed[i, p - 1] > k)):
                    listed_d[i, p] = listed_d[i, p - 1]
                    listed[i, p] = listed[i, p - 1]
                    p -= 1
                listed_d[i, p] = d
                listed[i, p] = k
        settle(i, m, s1 - s0 - 1 <= near)  # type: ignore[no-untyped-call]  # numba closure

    todo = np.empty(n, np.int64)
    for i in range(n):
        if rows_bound:
            list_first(i)  # type: ignore[no-untyped-call]  # numba closure
        else:
            list_anew(i)  # type: ignore[no-untyped-call]  # numba closure
        relink(i)  # type: ignore[no-untyped-call]  # numba closure
        tree[size + i] = i
    for v in range(size - 1, 0, -1):
        tree[v] = first(tree[2 * v], tree[2 * v + 1])  # type: ignore[no-untyped-call]  # numba closure
    count = n
    while count > max_groups and n > 0:
        i = tree[1]
        if best[i] == inf:
            break  # one group per kind left
        j = partner[i]
        a = min(i, j)
        b = max(i, j)
        r0[a] = min(r0[a], r0[b])
        c0[a] = min(c0[a], c0[b])
        r1[a] = max(r1[a], r1[b])
        c1[a] = max(c1[a], c1[b])
        alive[b] = False
        kr0[pos[a]] = r0[a]
        kc0[pos[a]] = c0[a]
        kr1[pos[a]] = r1[a]
        kc1[pos[a]] = c1[a]
        kr0[pos[b]] = -far
        kc0[pos[b]] = -far
        kr1[pos[b]] = far
        kc1[pos[b]] = far
        best[b] = inf
        joined[b] = a
        update(b)  # type: ignore[no-untyped-call]  # numba closure
        count -= 1
        m = 0
        for p in (a, b):  # the living boxes whose partner was a or b (those of a box without one: no matter)
            k = head[p]
            while k >= 0:
                if k != a and alive[k]:
                    todo[m] = k
                    m += 1
                k = nxt[k]
        for t in range(m):
            k = todo[t]
            refresh(k)  # type: ignore[no-untyped-call]  # numba closure
            relink(k)  # type: ignore[no-untyped-call]  # numba closure
            update(k)  # type: ignore[no-untyped-call]  # numba closure
        relist_merged(a, b)  # type: ignore[no-untyped-call]  # numba closure
        relink(a)  # type: ignore[no-untyped-call]  # numba closure
        update(a)  # type: ignore[no-untyped-call]  # numba closure
    rep = np.empty(n, np.int64)
    for k in range(n):  # joined[k] <= k: the representatives of the lower boxes are known
        rep[k] = k if joined[k] == k else rep[joined[k]]
    return rep


def _merge_compact(boxes: np.ndarray, kind: np.ndarray, max_groups: int) -> np.ndarray:
    """Agglomerate boxes into at most ``max_groups`` groups, never across kinds: repeatedly merge the
    pair whose united bounding box has the smallest diagonal (lowest indices on ties).

    Returns the group of each box as the index of its representative box.
    """
    rep: np.ndarray = _merge_kernel(np.ascontiguousarray(boxes, dtype=np.int64),
                                    np.ascontiguousarray(kind, dtype=np.int64), int(max_groups), NEAR)
    return rep


@numba.njit(cache=True)
def _primary_and_suspects(codes, n_det, primary):  # type: ignore[no-untyped-def]  # numba kernel
    """``primary`` (int8, ``codes``' shape) gets each pixel's first detector (the lowest of the bits 0 ..
    n_det - 1 set in ``codes``; -1 for none), in one pass for the loop of masked writes it replaces; returns
    the flat indices of the pixels with one, in raster order (``np.flatnonzero(primary >= 0)``)."""
    c = codes.reshape(-1)
    pr = primary.reshape(-1)
    bits = (1 << n_det) - 1
    first = np.full(bits + 1, -1, np.int8)  # the lowest bit set of each combination of the detectors' bits
    for v in range(bits, 0, -1):
        for i in range(n_det - 1, -1, -1):
            if (v >> i) & 1:
                first[v] = i
    n = 0
    for p in range(c.size):
        v = c[p] & bits
        pr[p] = first[v]
        n += v != 0
    sus = np.empty(n, np.int64)
    k = 0
    for p in range(c.size):
        if pr[p] >= 0:
            sus[k] = p
            k += 1
    return sus


@numba.njit(cache=True)
def _label_classes(values, labels, n, bounds):  # type: ignore[no-untyped-def]  # numba kernel
    """``np.searchsorted(bounds, label_medians(values, labels, n), side="right")`` as int8: for each label
    1..n, how many of the increasing ``bounds`` the median of its finite values reaches (all of them for
    a label with none: NaN sorts last). Each label's values are sorted on their own (a counting sort by
    label, then ``np.sort``) instead of one lexsort of all: the same values in the same order but for the
    sign of a zero, which no median compared with the bounds can tell.
    """
    buf, start, count = label_gather(values, labels, n)
    out = np.empty(n, np.int8)
    for g in range(1, n + 1):
        c = count[g]
        if c == 0:
            out[g - 1] = bounds.size
            continue
        s0 = start[g]
        if c == 1:  # most labels: one or two values, no sort (a + b is b + a)
            med = buf[s0]
        elif c == 2:
            med = 0.5 * (buf[s0] + buf[s0 + 1])
        else:
            seg = np.sort(buf[s0:s0 + c])
            lo = (c - 1) // 2
            hi = c // 2
            med = seg[lo] if lo == hi else 0.5 * (seg[lo] + seg[hi])
        k = 0
        while k < bounds.size and bounds[k] <= med:
            k += 1
        out[g - 1] = k
    return out


def strength_classes(primary: np.ndarray, strength: np.ndarray, *, _sus: np.ndarray | None = None) -> np.ndarray:
    """The strength class of each suspect pixel (0, 1, 2; -1 where ``primary`` is -1).

    Per detector, the 8-connected components of its pixels take the median of their pixels'
    ``strength`` (|gap| / τ); the class is the number of :data:`STRENGTH_CLASSES` bounds that median
    reaches (NaN, no surface to measure against: the strongest class).

    Parameters
    ----------
    primary : (H, W) int ndarray
        Each pixel's grouping detector (index into :data:`DETECTORS`), -1 for no suspect.
    strength : (H, W) float ndarray
        |gap| / τ of each pixel.
    """
    primary = np.asarray(primary)
    out = np.full(primary.shape, -1, np.int8)
    flat_p = primary.reshape(-1)
    sus = np.flatnonzero(flat_p >= 0) if _sus is None else _sus
    if sus.size == 0:
        return out
    det = flat_p[sus]
    by_det = np.argsort(det, kind="stable")  # each detector's pixels in raster order
    ends = np.searchsorted(det[by_det], np.arange(len(DETECTORS) + 1), side="left")
    s = np.asarray(strength, np.float64).reshape(-1)[sus]
    s = np.where(np.isfinite(s), s, np.inf)
    flat_out = out.reshape(-1)
    for i in range(len(DETECTORS)):
        sel = by_det[ends[i]:ends[i + 1]]
        if sel.size == 0:
            continue
        lab, n, _ = _kind_components(sus[sel], primary.shape, 0)  # ndimage.label's 8-connected components
        cls = _label_classes(s[sel], lab, n, np.asarray(STRENGTH_CLASSES, np.float64))  # of the medians
        flat_out[sus[sel]] = cls[lab - 1]
    return out


def group_suspects(codes: np.ndarray, strength: np.ndarray, params: SuspectParams
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group labels (unordered), each group's primary detector, and the merge radius of each detector.

    Per detector (a pixel belongs to the first of its detectors in :data:`DETECTORS`) and strength
    class (:func:`strength_classes`: one decision must fit a group, and suspects at the noise's edge
    are not judged like those far off the surface), the suspects within ``merge_radius_px`` form
    components (the radius doubles while one has more than ``MAX_NODES``); then, while the frame has
    more than ``max_groups`` groups, the two groups of one detector and class whose united bounding
    box is smallest merge (:func:`_merge_compact`), and only when that is not enough, groups of one
    detector across classes: groups stay compact regions a person can zoom to, a large blob stays
    alone, specks near each other join.
    """
    primary = np.empty(codes.shape, np.int8)  # the first detector in DETECTORS wins
    # the suspects' flat indices in raster order
    sus = _primary_and_suspects(np.ascontiguousarray(codes), len(DETECTORS), primary)
    cls = strength_classes(primary, strength, _sus=sus)
    n_cls = len(STRENGTH_CLASSES) + 1
    radii = np.full(len(DETECTORS), params.merge_radius_px, np.int64)
    limit = max(codes.shape)
    # the suspects' flat indices by detector and class, each in raster order
    fine_of = primary.ravel()[sus].astype(np.int64) * n_cls + cls.ravel()[sus]
    by_kind = np.argsort(fine_of, kind="stable")
    ends = np.searchsorted(fine_of[by_kind], np.arange(len(DETECTORS) * n_cls + 1), side="left")
    per = []
    fine = []
    for i in range(len(DETECTORS)):
        for c in range(n_cls):
            f = i * n_cls + c
            flat = sus[by_kind[ends[f]:ends[f + 1]]]
            r = int(params.merge_radius_px)
            lab, n, bx = _kind_components(flat, codes.shape, r)
            while n > MAX_NODES and r < limit:
                r = min(2 * r + 1, limit)
                lab, n, bx = _kind_components(flat, codes.shape, r)
            radii[i] = max(radii[i], r)
            per.append((flat, lab, n, bx))
            fine.append(f)
    offsets = np.cumsum([0] + [n for _, _, n, _ in per])
    total = int(offsets[-1])
    boxes = np.zeros((total, 4), np.int64)
    kind = np.zeros(total, np.int64)
    for i, (_, _, n, bx) in enumerate(per):
        if n:
            boxes[offsets[i]:offsets[i + 1]] = bx
            kind[offsets[i]:offsets[i + 1]] = fine[i]
    rep = _merge_compact(boxes, kind, params.max_groups) if total > params.max_groups else np.arange(total)
    if np.unique(rep).size > params.max_groups:  # more detector-and-class kinds than groups: join classes
        heads = np.unique(rep)
        hb = np.array([[boxes[rep == h, 0].min(), boxes[rep == h, 1].min(), boxes[rep == h, 2].max(),
                        boxes[rep == h, 3].max()] for h in heads], np.int64)
        rep2 = _merge_compact(hb, kind[heads] // n_cls, params.max_groups)
        rep = heads[rep2[np.searchsorted(heads, rep)]]
    kind //= n_cls
    _, dense = np.unique(rep, return_inverse=True)
    node_group = np.concatenate([[0], dense + 1]).astype(np.int32)
    groups = np.zeros(codes.shape, np.int32)
    kinds = np.zeros(int(dense.max()) + 1 if total else 0, np.uint8)
    kinds[dense] = kind
    flat_groups = groups.reshape(-1)
    for i, (flat, lab, n, _) in enumerate(per):
        if n:
            flat_groups[flat] = node_group[lab + offsets[i]]
    return groups, kinds, radii
