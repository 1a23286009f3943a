"""The shaft detector's shortcuts read what the plain computation reads: the instrument mask's
RANSAC over its outline (`shaft.mask`), and the region boundaries read once per frame and
reused by the cues (`shaft.regions`)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft import mask as mask_mod
from pencilcal.toolkit.detect.shaft import regions
from pencilcal.toolkit.detect.shaft.regions import boundary_lines_many


def _plain_best_stretch(P, usable, rng, tol, gap, min_len):
    """The RANSAC of `mask._best_stretch` line by line, every run of every line scanned (the
    reading the references of the scores were made with), then its refit."""
    cand = np.flatnonzero(usable)
    best = None
    for _ in range(mask_mod._RANSAC_ITERS):
        i, j = rng.choice(cand, 2, replace=False)
        d = P[j] - P[i]
        L = np.hypot(*d)
        if L < 0.5 * min_len:
            continue
        u = d / L
        for run in mask_mod._runs((np.abs((P - P[i]) @ np.array([-u[1], u[0]])) < tol) & usable, gap):
            if best is None or run.size > best.size:
                best = run
    for _ in range(2):
        c, u, n = mask_mod._line_tls(P[best].astype(float))
        runs = [q for q in mask_mod._runs((np.abs((P - c) @ n) < tol) & usable, gap) if np.intersect1d(q, best).size]
        if not runs:
            break
        best = max(runs, key=len)
    return best


def _outline(seed):
    """(contour (N, 2) int, usable (N,) bool) of a random instrument-like mask: a band from
    the border with a jaw and a notch, at a random angle."""
    rng = np.random.default_rng(seed)
    m = np.zeros((360, 640), np.uint8)
    a = rng.uniform(0, np.pi)
    c = np.array([320.0, 180.0]) + rng.uniform(-60, 60, 2)
    u, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    w = rng.uniform(15, 60)
    quad = np.array([c - 500 * u - w * n, c + rng.uniform(50, 200) * u - w * n,
                     c + rng.uniform(50, 200) * u + w * n, c - 500 * u + w * n])
    cv2.fillConvexPoly(m, np.rint(quad).astype(np.int32), 1)
    cv2.circle(m, tuple(np.rint(c + 0.5 * w * n).astype(int)), int(rng.uniform(5, 25)), 0, -1)
    cs, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    C = max(cs, key=len)[:, 0, :]
    usable = (C[:, 0] > 2) & (C[:, 0] < 637) & (C[:, 1] > 2) & (C[:, 1] < 357)
    return C, usable


@pytest.mark.parametrize("seed", range(6))
def test_batched_ransac_reads_the_plain_one_s_stretch(seed):
    C, usable = _outline(seed)
    got = mask_mod._best_stretch(C, usable, np.random.default_rng(seed), 2.5, 10, 40.0)
    want = _plain_best_stretch(C, usable, np.random.default_rng(seed), 2.5, 10, 40.0)
    assert want is not None and np.array_equal(got, want)
    # the generator left where the plain loop leaves it (the next stretch draws the same lines)
    r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
    mask_mod._best_stretch(C, usable, r1, 2.5, 10, 40.0)
    _plain_best_stretch(C, usable, r2, 2.5, 10, 40.0)
    assert r1.integers(1 << 30) == r2.integers(1 << 30)


@pytest.mark.parametrize("K", [2, 3, 10, 57, 1000, 70000])
def test_pairs_drawn_at_once_are_rng_choice_s_one_by_one(K):
    """The RANSAC's pairs drawn together are numpy's rng.choice(cand, 2, replace=False) in turn,
    and leave the generator where those calls leave it."""
    cand = np.sort(np.random.default_rng(K).choice(10 * K, K, replace=False))
    for seed in range(3):
        r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
        got = mask_mod._pairs_drawn(r1, cand, 600)
        want = np.array([r2.choice(cand, 2, replace=False) for _ in range(600)])
        assert np.array_equal(got, want)
        assert r1.bit_generator.state == r2.bit_generator.state


def test_pairs_drawn_where_lemire_rejects_a_word_fall_back_to_the_calls():
    """Where a word fails Lemire's bias test (of 99991 candidates, seed 13 draws one among its
    first 3000 pairs) the draws are made one by one: the pairs and the generator's state are
    rng.choice's."""
    K = 99991
    ex = np.array([K - 1, K, 2], np.uint64)
    m = np.random.default_rng(13).integers(0, 2**32, size=(3000, 3), dtype=np.uint32).astype(np.uint64) * ex
    assert np.any((m & np.uint64(0xFFFFFFFF)) < np.uint64(2**32) % ex)  # the case is the fallback's
    cand = np.arange(K) * 3
    r1, r2 = np.random.default_rng(13), np.random.default_rng(13)
    got = mask_mod._pairs_drawn(r1, cand, 3000)
    want = np.array([r2.choice(cand, 2, replace=False) for _ in range(3000)])
    assert np.array_equal(got, want) and r1.bit_generator.state == r2.bit_generator.state


def test_longest_run_is_the_first_longest_of_the_runs():
    rng = np.random.default_rng(1)
    for _ in range(300):
        flag = rng.random(int(rng.integers(1, 80))) < rng.uniform(0.1, 0.9)
        gap = int(rng.integers(0, 4))
        runs = mask_mod._runs(flag, gap)
        got = mask_mod._longest_run(flag, gap)
        if not runs:
            assert got is None
            continue
        first = runs[0]
        for r in runs:
            first = r if r.size > first.size else first
        assert np.array_equal(got, first)


def test_max_run_sizes_are_the_runs_longest_row_by_row():
    rng = np.random.default_rng(2)
    for _ in range(60):
        N, gap = int(rng.integers(1, 60)), int(rng.integers(0, 4))
        flags = rng.random((int(rng.integers(1, 12)), N)) < rng.uniform(0.05, 0.95)
        flags[0] = False                                                   # a row with no run
        want = [max((r.size for r in mask_mod._runs(f, gap)), default=0) for f in flags]
        assert mask_mod._max_run_sizes(flags, gap).tolist() == want


def test_boundary_lines_read_again_are_the_same_and_follow_a_changed_map():
    maps = [np.zeros((120, 160), np.uint8) for _ in range(2)]
    maps[0][20:70, 10:150] = 1
    maps[1][40:110, 30:90] = 1
    dist = np.full((120, 160), 50.0, np.float32)
    first = boundary_lines_many(maps, dist, 10.0)
    again = boundary_lines_many([m.copy() for m in maps], dist.copy(), 10.0)
    assert [len(L.p) for L in first] == [len(L.p) for L in again] and all(len(L.p) for L in first)
    assert all(np.array_equal(a.p, b.p) and np.array_equal(a.hi, b.hi) for a, b in zip(first, again))
    maps[0][:] = 0                                           # the same array, changed in place
    maps[0][60:100, 20:60] = 1
    changed = boundary_lines_many(maps, dist, 10.0)
    alone = [regions.boundary_lines(m.copy(), dist, 10.0) for m in maps]
    assert len(changed[0].p) != len(first[0].p) or not np.array_equal(changed[0].p, first[0].p)
    assert all(np.array_equal(a.p, b.p) and np.array_equal(a.lo, b.lo) for a, b in zip(changed, alone))
    # another least side is another reading
    assert sum(len(L.p) for L in boundary_lines_many(maps, dist, 1000.0)) == 0


def _grey_shafts_on_tissue():
    """A colour frame (480, 640, 3): pink tissue with a grey shaft from the left border and a
    dark one cut lengthwise by the bottom border."""
    img = np.zeros((480, 640, 3), np.uint8)
    img[:] = (90, 110, 200)
    img += np.random.default_rng(3).integers(0, 6, img.shape).astype(np.uint8)
    cv2.fillConvexPoly(img, np.array([[0, 150], [0, 200], [420, 260], [420, 215]], np.int32), (70, 70, 72))
    cv2.fillConvexPoly(img, np.array([[200, 479], [640, 400], [640, 479]], np.int32), (40, 40, 42))
    return img


def test_a_frame_s_regions_are_computed_once_and_read_by_both_cues(monkeypatch):
    from pencilcal.toolkit.detect.shaft import border_band, detector, material_cue

    calls, seen = {"levels": 0, "lines": 0}, {}
    levels, lines = regions.region_levels, regions.boundary_lines_many

    def counted_levels(*a, **k):
        calls["levels"] += 1
        return levels(*a, **k)

    def counted_lines(*a, **k):
        calls["lines"] += 1
        return lines(*a, **k)

    bands, seeds = material_cue._bands, border_band._seeds

    def material_bands(work, mm, frame_regions, *a):
        seen["material"] = frame_regions
        return bands(work, mm, frame_regions, *a)

    def border_seeds(frame_regions):
        seen["border"] = frame_regions
        return seeds(frame_regions)

    monkeypatch.setattr(regions, "region_levels", counted_levels)
    monkeypatch.setattr(regions, "boundary_lines_many", counted_lines)
    monkeypatch.setattr(material_cue, "_bands", material_bands)
    monkeypatch.setattr(border_band, "_seeds", border_seeds)
    detector.detect_shafts(_grey_shafts_on_tissue())
    assert calls == {"levels": 1, "lines": 1}
    assert seen["material"] is seen["border"] and len(seen["material"].lines) >= 1
    # the lines read are the boundaries of each level's map that is no repeat
    maps = [Bm for _, _, Bm, repeat in seen["material"].levels if not repeat]
    assert len(maps) == len(seen["material"].lines)
