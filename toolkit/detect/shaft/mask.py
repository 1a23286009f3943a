"""Instruments in a segmentation mask, and the axis each mask gives by its own outline.

A lab's segmentation network (or an annotator) marks the instrument pixels. Two readings of
such a mask serve pencilcal: the instruments it holds (`instruments_in_mask`: one boolean
mask per instrument, from a binary mask's connected components, a label image's selected
values, or an instance image's ids) and the axis each one's outline gives (`mask_axis`),
which is the reference of the detector's scores (`validation.shaft_score`) and where a
mask-guided detection starts.

`mask_axis` looks for the two silhouette edges on the instrument's outer contour:

1. the contour, less its points on the image border or on the valid region's boundary (the
   mask stops there; that is no silhouette);
2. the straight stretches of the contour, longest first (RANSAC: a line through two contour
   points, its inliers within `tol` px, and among them the longest run of contour-consecutive
   inliers, gaps of up to `gap` points bridged; then the next on the points left): a
   silhouette edge is one contiguous stretch of the boundary;
3. each with its partner, the longest stretch within `MAX_EDGE_ANGLE_DEG` of it on the
   mask's side, the mask between them; of these pairs, the one whose straight band (overlap
   along the axis times the width) is largest among the bands that no other band separates
   from where the instrument enters the view (the outline's points on the image border or
   the valid region's boundary; cut across at a band's middle, the mask's pieces that hold
   no entry point hold the bands beyond it, past its end): where the shaft is in view, its
   two edges (a clip applier's or a jaw's single edge may be longer, a prong's pair longer
   but narrow, and two open jaws' outer edges a wider band, but beyond the shaft);
   where it shares an edge with the pair of the longest stretch and runs within
   `SAME_AXIS_DEG` of it, that pair stands (a straight instrument: one axis);
4. each edge refitted by total least squares to its run; the straight part is where both
   runs overlap along the axis (a wrist, jaws or a hook beyond it are left out: their outline
   is not on these two lines).

The axis is then the plane bisector of the two edges (`axis.plane_bisector`, the construction
the detector uses). A mask with no such pair of edges (the distal part alone: jaws, a hook, a
clip applier with the shaft out of view) gets its principal axis instead, kind ``"part"``:
the direction of the largest second moment of its pixels, through their centroid, good to a
few degrees for an elongated part and meaningless for a round one (`MaskAxis.elongation`).

Pixels: raw image pixels, (0, 0) the centre of the top-left pixel; lines (3,) homogeneous
with a^2 + b^2 = 1.

Example
-------
>>> import numpy as np
>>> m = np.zeros((200, 300), bool); m[80:120, :200] = True            # a band from the border
>>> ax = mask_axis(m)
>>> ax.kind, [round(float(v), 2) + 0.0 for v in ax.line], round(ax.width_px), round(ax.length_px)
('shaft', [0.0, 1.0, -99.5], 40, 196)
>>> blob = np.zeros((200, 300), bool); blob[90:110, 100:160] = True       # edges too short for a shaft
>>> part = mask_axis(blob, min_edge_px=80)
>>> part.kind, [round(float(v), 2) + 0.0 for v in part.line[:2]], round(part.elongation, 1)
('part', [0.0, 1.0], 3.0)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.shaft.axis import plane_bisector
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.projective import line_through

__all__ = ["MaskAxis", "mask_axis", "instruments_in_mask", "MIN_INSTRUMENT_AREA", "MERGE_GAP_PX", "MAX_EDGE_ANGLE_DEG",
           "SAME_AXIS_DEG"]

#: The least area of an instrument in a mask [px]: below it a component is a speck of the
#: annotation, not an instrument.
MIN_INSTRUMENT_AREA = 200
#: Pieces of a mask this close are one instrument [px]: an annotator draws a shaft, its wrist
#: and its jaws as polygons with a gap of a pixel or two between them.
MERGE_GAP_PX = 5.0
#: The largest angle between a shaft's two silhouette edges [deg] (a shaft seen end-on from
#: close by converges by a few degrees).
MAX_EDGE_ANGLE_DEG = 12.0
#: Two pairs of silhouette edges sharing one edge and this close in direction [deg] read one
#: axis (a straight instrument's tip and shaft; the detector's own bound for two readings of
#: one instrument).
SAME_AXIS_DEG = 3.0
_RANSAC_ITERS = 600
_BATCH = 64  # lines whose inliers are counted together (memory: _BATCH x contour length)
#: The straight stretches of an outline paired into silhouette edges (`_two_edges`): a shaft's
#: two, its wrist's and jaws' a few more.
_MAX_STRETCHES = 8


@dataclass(frozen=True, eq=False)
class MaskAxis:
    """The axis an instrument's mask gives (`mask_axis`).

    Attributes
    ----------
    line : (3,)
        The axis image [raw px], a^2 + b^2 = 1.
    point : (2,) [px]
        Its point in the middle of the straight part (kind "shaft") or the mask's centroid.
    kind : str
        "shaft": two straight silhouette edges were found; "part": the principal axis of a
        mask without them (a distal part alone).
    width_px, length_px : float
        Apparent width across the axis (at `point`) and the length along which both edges are
        seen [px]; for a part, the extent of the mask across and along its principal axis.
    elongation : float
        Length over width (how well the principal axis of a part is defined).
    edges : (2, 4) or None
        The two straight silhouette stretches as segments [x1, y1, x2, y2] (kind "shaft").
    area : int
        The instrument's pixels in the mask.
    """

    line: np.ndarray
    point: np.ndarray
    kind: str
    width_px: float
    length_px: float
    elongation: float
    edges: np.ndarray | None
    area: int

    def segment(self) -> np.ndarray:
        """(4,) the axis drawn over the straight part (or the part's length), centred on
        `point` [px]."""
        d = np.array([self.line[1], -self.line[0]])
        h = 0.5 * self.length_px
        return np.r_[self.point - h * d, self.point + h * d]


def instruments_in_mask(mask, labels=None, instances=False, min_area=MIN_INSTRUMENT_AREA, merge_gap_px=MERGE_GAP_PX):
    """One boolean mask per instrument of a mask image.

    Parameters
    ----------
    mask : (H, W) or (H, W, 3) array
        A binary mask (any non-zero value is instrument), a label image (each value a class or
        a part) or an instance image (each value one instrument). A colour mask is read as
        instrument wherever it is not black.
    labels : sequence of int or of (B, G, R), optional
        The values that are instrument (e.g. a part label image's shaft label), or the colours
        of a colour mask that are; default every non-zero value (every non-black colour).
    instances : bool
        Each selected value is one instrument (an instance image), however many pieces it has;
        otherwise each connected component of the selected pixels is one (pieces closer than
        merge_gap_px joined).
    min_area : int
        Smaller instruments are left out [px].
    merge_gap_px : float
        Components closer than this are one instrument [px] (`MERGE_GAP_PX`).

    Returns
    -------
    list of (H, W) bool
        Largest first.

    Example
    -------
    >>> import numpy as np
    >>> m = np.zeros((50, 80), np.uint8); m[5:15, 10:70] = 10; m[30:40, 10:70] = 20; m[20:25, :] = 30
    >>> [int(x.sum()) for x in instruments_in_mask(m, labels=[10, 20], min_area=100)]
    [600, 600]
    >>> len(instruments_in_mask(m, instances=True, min_area=100))
    3
    """
    import cv2

    m = np.asarray(mask)
    if m.ndim == 3 and labels is not None and all(np.ndim(v) == 1 for v in labels):
        # colour labels (B, G, R): each selected colour a value of a label image
        m3 = m[..., :3]
        lab = np.zeros(m.shape[:2], np.int32)
        for k, v in enumerate(labels, 1):
            lab[np.all(m3 == np.asarray(v, m3.dtype), axis=-1)] = k
        m, labels = lab, list(range(1, len(labels) + 1))
    elif m.ndim == 3:
        m = np.any(m[..., :3] != 0, axis=-1).astype(np.uint8)
    if m.ndim != 2:
        raise InputError(f"mask: expected (H, W) or (H, W, 3), got shape {m.shape}")
    values = [int(v) for v in np.unique(m) if v != 0] if labels is None else [int(v) for v in labels]
    out = []
    if instances:
        out = [m == v for v in values]
    else:
        sel = np.isin(m, values).astype(np.uint8)
        r = int(np.ceil(0.5 * merge_gap_px))
        grown = cv2.dilate(sel, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))) if r else sel
        n, lab = cv2.connectedComponents(grown, connectivity=8)
        out = [(lab == k) & (sel > 0) for k in range(1, n)]
    out = [x for x in out if int(x.sum()) >= min_area]
    return sorted(out, key=lambda x: -int(x.sum()))


def _line_tls(P):
    c = P.mean(0)
    u = np.linalg.svd(P - c, full_matrices=False)[2][0]
    return c, u, np.array([-u[1], u[0]])


def _runs(flag, gap):
    """Runs of True in a cyclic bool array, bridging gaps of up to `gap` False: index arrays."""
    order, breaks = _run_order(flag, gap)
    return [] if order is None else [r % flag.size for r in np.split(order, breaks)]


def _run_order(flag, gap):
    """The True indices of a cyclic bool array in run order (starting after the widest gap,
    unwrapped past the end) and where its runs break (`_runs`), or (None, None)."""
    N = flag.size
    idx = np.flatnonzero(flag)
    if idx.size == 0:
        return None, None
    d = np.diff(np.r_[idx, idx[0] + N])
    start = (np.argmax(d) + 1) % idx.size
    order = np.r_[idx[start:], idx[:start] + N]
    return order, np.flatnonzero(np.diff(order) > gap + 1) + 1


def _longest_run(flag, gap):
    """The first of the longest runs of `_runs(flag, gap)` (index array), or None: the one a
    scan of the runs that keeps only a strictly longer one ends with, without splitting them
    all."""
    order, breaks = _run_order(flag, gap)
    if order is None:
        return None
    edges = np.r_[0, breaks, order.size]
    k = int(np.argmax(np.diff(edges)))
    return order[edges[k]:edges[k + 1]] % flag.size


def _max_run_sizes(flags, gap):
    """The size of the longest run of `_runs(flag, gap)` of each row of flags (B, N) bool
    (0 where none), all rows at once: the True entries in row order, a run broken where the
    next one is over gap + 1 on, the row's first and last runs one where the gap round the end
    is not."""
    B, N = flags.shape
    out = np.zeros(B, int)
    r, c = np.nonzero(flags)
    if r.size == 0:
        return out
    new = np.r_[True, (r[1:] != r[:-1]) | (np.diff(c) > gap + 1)]
    gid = np.cumsum(new) - 1
    size = np.bincount(gid)
    first = np.flatnonzero(new)                     # each run's first entry
    row = r[first]
    head = np.r_[True, row[1:] != row[:-1]]         # a row's first run
    tail = np.r_[row[1:] != row[:-1], True]         # a row's last run
    hi, ti = np.flatnonzero(head), np.flatnonzero(tail)
    c_first, c_last = c[first[hi]], c[np.r_[first[1:], r.size][ti] - 1]
    wrap = (hi != ti) & (c_first + N - c_last <= gap + 1)
    joined = size[hi[wrap]] + size[ti[wrap]]
    size[hi[wrap]], size[ti[wrap]] = joined, joined
    np.maximum.at(out, row, size)
    return out


def _pairs_drawn(rng, cand, n):
    """(n, 2) pairs of distinct elements of cand (K,), K >= 2: the pairs, and the generator's
    state after them, of n calls ``rng.choice(cand, 2, replace=False)`` in turn, drawn at
    once (a call costs ~50 us; 600 of them were a tenth of the shaft detector's time).

    numpy's Generator draws two of K without replacement by Floyd's algorithm: a bounded
    draw in [0, K-2], one in [0, K-1] (K-1 where it repeats the first), then a shuffle of the
    two (a draw in [0, 1]: 0 swaps them), each bounded draw one 32-bit word scaled by
    Lemire's method. The words are drawn together; where any would be rejected by Lemire's
    bias test (about one in 2^32 / K draws) the generator's state is restored and the calls
    made one by one. tests/toolkit/detect/shaft/test_mask_speed.py holds it to rng.choice.
    """
    K = cand.size
    state = rng.bit_generator.state
    ex = np.array([K - 1, K, 2], np.uint64)  # each bounded draw's count of values
    m = rng.integers(0, 2**32, size=(n, 3), dtype=np.uint32).astype(np.uint64) * ex
    # (of two, the first draw has one value and takes no word)
    if K < 3 or np.any((m & np.uint64(0xFFFFFFFF)) < np.uint64(2**32) % ex):
        rng.bit_generator.state = state
        return np.array([rng.choice(cand, 2, replace=False) for _ in range(n)])
    v = (m >> np.uint64(32)).astype(np.int64)
    a, b = v[:, 0], np.where(v[:, 1] == v[:, 0], K - 1, v[:, 1])
    swap = v[:, 2] == 0
    return cand[np.stack([np.where(swap, b, a), np.where(swap, a, b)], 1)]


def _best_stretch(P, usable, rng, tol, gap, min_len, constraint=None):
    """The longest run of contour points P (N, 2) on one line (index array), or None.

    `_RANSAC_ITERS` lines through two usable points drawn from rng, in turn: each line's run
    of inliers (`_longest_run`) replaces the best so far where it is longer. The draws are
    made first and the longest run of each of a batch of lines measured together
    (`_max_run_sizes`): the same draws and runs as one line at a time; a line whose longest
    run is no longer than the best is passed by, the others' runs taken (`_longest_run`)."""
    cand = np.flatnonzero(usable)
    if cand.size < 10:
        return None
    ij = _pairs_drawn(rng, cand, _RANSAC_ITERS)
    D = P[ij[:, 1]] - P[ij[:, 0]]
    L = np.hypot(D[:, 0], D[:, 1])
    ok = L >= 0.5 * min_len
    U = D / np.where(ok, L, 1.0)[:, None]
    if constraint is not None:
        ok[ok] = [constraint(U[k], P[ij[k, 0]]) for k in np.flatnonzero(ok)]
    keep = np.flatnonzero(ok)
    X, Y = P[:, 0].astype(float), P[:, 1].astype(float)
    best = None
    for b in range(0, keep.size, _BATCH):
        k = keep[b:b + _BATCH]
        i = ij[k, 0]
        # distances (lines, N) to the lines through P[i] across n = (-u_y, u_x)
        flags = (np.abs((X[None, :] - X[i, None]) * -U[k, 1, None] + (Y[None, :] - Y[i, None]) * U[k, 0, None]) < tol)
        flags &= usable
        longest = _max_run_sizes(flags, gap)
        for r in range(k.size):
            if best is not None and longest[r] <= best.size:
                continue
            run = _longest_run(flags[r], gap)
            if run is not None and (best is None or run.size > best.size):
                best = run
    if best is None:
        return None
    for _ in range(2):  # refit to the run and take the run again
        c, u, n = _line_tls(P[best].astype(float))
        runs = [q for q in _runs((np.abs((P - c) @ n) < tol) & usable, gap) if np.intersect1d(q, best).size]
        if not runs:
            break
        best = max(runs, key=len)
    return best


def _principal(P):
    """(centroid, direction, extent along, extent across) of a mask's pixels P (N, 2) [x, y]."""
    c, u, n = _line_tls(P)
    s, t = (P - c) @ u, (P - c) @ n
    return c, u, float(s.max() - s.min() + 1), float(t.max() - t.min() + 1)


def mask_axis(mask, valid=None, K=None, *, tol=2.5, gap=10, min_edge_px=40.0, seed=0):
    """The axis of one instrument's mask (module docstring).

    Parameters
    ----------
    mask : (H, W) bool
        One instrument (`instruments_in_mask`).
    valid : (H, W) bool, optional
        The valid region's mask: the outline on its boundary is no silhouette.
    K : (3, 3), optional
        The camera matrix the plane bisector is taken with; default the nominal pinhole (focal
        length the image width, centre in the middle) the detector uses without a camera.
    tol, gap : float, int
        A silhouette stretch: contour points within tol px of its line, gaps of up to gap
        points bridged.
    min_edge_px : float
        Shortest silhouette stretch [contour points ~ px]; shorter ones give kind "part".
    seed : int
        The RANSAC's seed (the axis is repeatable).

    Returns
    -------
    MaskAxis or None
        None when the mask is empty.
    """
    import cv2

    m = np.asarray(mask, bool)
    if not m.any():
        return None
    H, W = m.shape
    if K is None:
        K = np.array([[W, 0.0, 0.5 * (W - 1)], [0.0, W, 0.5 * (H - 1)], [0, 0, 1]])
    ys, xs = np.nonzero(m)
    P = np.c_[xs, ys].astype(float)  # the mask's pixels, found once (a full-frame scan each time)
    area = len(P)
    c0, u0, along, across = _principal(P)
    l0 = np.r_[-u0[1], u0[0], u0[1] * c0[0] - u0[0] * c0[1]]
    part = MaskAxis(line=l0 if l0[1] > 0 or (l0[1] == 0 and l0[0] > 0) else -l0, point=c0, kind="part",
                    width_px=across, length_px=along, elongation=along / across, edges=None, area=area)
    cs, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    C = max(cs, key=len)[:, 0, :]
    usable = (C[:, 0] > 2) & (C[:, 0] < W - 3) & (C[:, 1] > 2) & (C[:, 1] < H - 3)
    if valid is not None:
        vb = cv2.erode(np.asarray(valid, np.uint8), np.ones((7, 7), np.uint8))
        usable &= vb[C[:, 1], C[:, 0]] > 0
    got = _two_edges(C, m, P, usable, np.random.default_rng(seed), tol, gap, min_edge_px)
    if got is None:
        return part
    (c1, u1, _), (c2, u2, _) = (_line_tls(C[r].astype(float)) for r in got)
    u2 = u2 if u2 @ u1 > 0 else -u2
    s1, s2 = C[got[0]] @ u1, C[got[1]] @ u1
    lo, hi = max(s1.min(), s2.min()), min(s1.max(), s2.max())
    if hi - lo < 0.5 * min_edge_px:
        return part
    # the contour runs through the mask's outermost pixel centres, half a pixel inside the
    # silhouette: each edge moved out by that much
    n1 = np.array([-u1[1], u1[0]])
    n1 = n1 if (c2 - c1) @ n1 > 0 else -n1
    c1, c2 = c1 - 0.5 * n1, c2 + 0.5 * n1
    s_mid = 0.5 * (lo + hi)
    p1 = c1 + (s_mid - c1 @ u1) * u1
    p2 = c2 + (s_mid - c2 @ u1) / (u2 @ u1) * u2
    mid = 0.5 * (p1 + p2)
    lines = [line_through(c, c + u) for c, u in ((c1, u1), (c2, u2))]
    la = plane_bisector(K, lines[0], lines[1], mid)
    la = la if la[1] > 0 or (la[1] == 0 and la[0] > 0) else -la   # one sign for one line
    point = mid - (la[:2] @ mid + la[2]) * la[:2]
    width = float(abs((p2 - p1) @ la[:2]))
    edges = np.array([np.r_[c1 + (lo - c1 @ u1) * u1, c1 + (hi - c1 @ u1) * u1],
                      np.r_[c2 + (lo - c2 @ u1) / (u2 @ u1) * u2, c2 + (hi - c2 @ u1) / (u2 @ u1) * u2]])
    return MaskAxis(line=la, point=point, kind="shaft", width_px=width, length_px=float(hi - lo),
                    elongation=float(hi - lo) / max(width, 1.0), edges=edges, area=area)


def _two_edges(C, m, P, usable, rng, tol, gap, min_len):
    """The two silhouette stretches (index arrays) of a contour C (N, 2) of the mask m (H, W)
    whose pixels are P (M, 2) [x, y], or None.

    The straight stretches of the outline, longest first (up to `_MAX_STRETCHES`), each with
    its partner: the longest stretch within `MAX_EDGE_ANGLE_DEG` of it on the mask's side, with
    the mask between the two. Of these pairs, the one whose straight band (where both
    stretches overlap along the axis, times the width between them) covers most of the mask,
    among the bands that no other band separates from where the instrument enters the view
    (`_beyond`: the contour on the image border or the valid region's boundary). An
    instrument with its shaft in view is read by its shaft: the jaws or a clip applier beyond
    the wrist may have a longer single straight edge, a jaw's prong two long edges close
    together, and two open jaws a wider band between their outer edges, but the shaft is the
    part that reaches the entry and the jaws lie beyond it. Where that band shares an edge
    with the first pair (the longest stretch's) and runs within `SAME_AXIS_DEG` of it, the
    first stands: a straight instrument, one axis.
    """
    best, best_area, first = None, 0.0, None
    bands = []   # every pair with the mask between its edges: (pair, area, middle line (9, 2), across (2,), width)
    us = usable.copy()
    for _ in range(_MAX_STRETCHES):
        run1 = _best_stretch(C, us, rng, tol, gap, min_len)
        if run1 is None or run1.size < min_len:
            break
        us[run1] = False
        if best is not None and any(np.intersect1d(run1, r).size > 0.5 * run1.size for r in best):
            continue  # an edge of the pair held, read again: the pair found first stands
        run2 = _partner(C, P, usable, rng, tol, gap, min_len, run1)
        if run2 is None:
            continue
        c1, u1, n1 = _line_tls(C[run1].astype(float))
        s1, s2 = C[run1] @ u1, C[run2] @ u1
        lo, hi = max(s1.min(), s2.min()), min(s1.max(), s2.max())
        off = float(np.median((C[run2] - c1) @ n1))
        if hi <= lo:
            continue
        # the band between them is the mask's (not the background between two prongs)
        s = np.linspace(lo, hi, 9)
        q = np.rint(c1 + (s - c1 @ u1)[:, None] * u1 + 0.5 * off * n1).astype(int)
        inside = (q[:, 0] >= 0) & (q[:, 0] < m.shape[1]) & (q[:, 1] >= 0) & (q[:, 1] < m.shape[0])
        if not (inside.all() and m[q[:, 1], q[:, 0]].mean() >= 0.75):
            continue
        pair = (run1, run2)
        bands.append((pair, (hi - lo) * abs(off), q, n1 * np.sign(off), abs(off)))
        if (hi - lo) * abs(off) > best_area:
            best, best_area = pair, (hi - lo) * abs(off)
            first = best if first is None else first
    if best is None:
        return None
    entry = C[~usable]
    if entry.size and len(bands) > 1:
        beyond = _beyond(C, m, entry, bands)
        near = [b for b, far in zip(bands, beyond) if not far]
        if near:
            best = max(near, key=lambda b: b[1])[0]
    if first is not best:
        # a straight instrument whose one silhouette edge runs on from its shaft to its tip:
        # one axis, and the pair of the longest edges stands; another part (a bend, a clip
        # applier, a jaw beside the axis) shares no edge with the shaft
        if _one_axis(C, best, first):
            return first
    return best


def _one_axis(C, pair, other):
    """Whether two pairs of stretches of contour C read one straight part: they share a
    stretch (more than half the shorter one) and run within `SAME_AXIS_DEG`."""
    shared = any(np.intersect1d(a, b).size > 0.5 * min(a.size, b.size) for a in pair for b in other)
    u, v = (_pair_direction(C, p) for p in (pair, other))
    return shared and abs(u @ v) >= np.cos(np.radians(SAME_AXIS_DEG))


def _beyond(C, m, entry, bands):
    """Per band, whether another band separates it from the instrument's entry (list of bool).

    C (N, 2) the contour; m (H, W) bool the instrument; entry (E, 2) its contour points where
    it enters the view; bands as `_two_edges` collects them: (pair, area, q (9, 2) points
    along the band's middle line, n (2,) across it, width). Band A is cut across at its middle
    (the mask's run along the cross line through that point, 3 px thick); band B lies beyond
    A when all of B's middle-line points left are in pieces of the mask that hold no entry
    point and B's middle is past A's end along A's axis: the instrument reaches B only
    through A (jaws beyond the shaft). A band overlapping A's middle, one across A centred on
    its cut, or one reading one axis with A (`_one_axis`: a straight instrument's shaft and
    closed tip, a converging shaft read in two sections) is not beyond it. Only a band seen
    along at least its width cuts: a shorter one has no direction to speak of (the reason of
    `parts.MIN_ELONGATION`), such as a stub of outline at the border paired with the shaft's
    long edge.
    """
    import cv2

    H, W = m.shape
    m8 = m.astype(np.uint8)
    far = [False] * len(bands)
    for a, (_, area, qa, na, wa) in enumerate(bands):
        if area < wa * wa:
            continue   # seen along less than its width: no straight part to speak of (a corner's stub)
        p = qa[4].astype(float)
        if not m[int(p[1]), int(p[0])]:
            continue   # the band's middle is not the mask's: no cut through it
        line = np.zeros_like(m8)
        h = 2.0 * wa + 10.0
        cv2.line(line, tuple(np.rint(p - h * na).astype(int)), tuple(np.rint(p + h * na).astype(int)), 1, 3)
        _, lab = cv2.connectedComponents(line & m8, connectivity=8)
        cut = lab == lab[int(p[1]), int(p[0])]
        _, rest = cv2.connectedComponents((m & ~cut).astype(np.uint8), connectivity=8)
        reached = set(np.unique(rest[entry[:, 1], entry[:, 0]]).tolist()) - {0}
        if not reached:
            continue
        ua = (qa[-1] - qa[0]).astype(float)
        half = 0.5 * np.hypot(*ua)
        ua /= max(2.0 * half, 1e-9)
        for b, (pb, _, qb, _, _) in enumerate(bands):
            if b == a or _one_axis(C, pb, bands[a][0]) or abs((qb[4] - qa[4]) @ ua) < half:
                continue   # the same part, or a band whose middle is not past A's end
            ok = (qb[:, 0] >= 0) & (qb[:, 0] < W) & (qb[:, 1] >= 0) & (qb[:, 1] < H)
            lb = rest[qb[ok, 1], qb[ok, 0]]
            lb = lb[lb > 0]
            if lb.size and not any(v in reached for v in lb.tolist()):
                far[b] = True
    return far


def _pair_direction(C, pair):
    """The mean direction (2,) of a pair of stretches: the axis' direction."""
    u1, u2 = (_line_tls(C[r].astype(float))[1] for r in pair)
    u = u1 + (u2 if u1 @ u2 > 0 else -u2)
    return u / np.linalg.norm(u)


def _partner(C, P, usable, rng, tol, gap, min_len, run1):
    """The longest stretch within `MAX_EDGE_ANGLE_DEG` of run1's line, on the side of it of
    the mask's pixels P (M, 2) [x, y] (index array), or None."""
    c1, u1, n1 = _line_tls(C[run1].astype(float))
    side = np.sign(np.median((P - c1) @ n1))
    us2 = usable.copy()
    us2[run1] = False
    cos_max = np.cos(np.radians(MAX_EDGE_ANGLE_DEG))

    def other_side(u, p0):
        return abs(u @ u1) >= cos_max and (p0 - c1) @ n1 * side > 3.0 * tol

    run2 = _best_stretch(C, us2, rng, tol, gap, min_len, constraint=other_side)
    return None if run2 is None or run2.size < min_len else run2
