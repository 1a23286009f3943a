"""The valid region of a sequence from its frames: letterbox bars, a circular field stop,
static overlays (`detect_valid_region`), and the region every detecting command uses
(`sequence_region`: a user's mask file, or the region detected from up to 16 frames).

Algorithm of `detect_valid_region` (thresholds: the named constants below, and
`region.circle`'s):

1. *frames*: up to `max_frames` sampled evenly; brightness is the channel maximum. ``hi``,
   the per-pixel maximum over the frames, is what is analysed: a moving dark instrument
   cannot punch a hole into it, and the surround is what stays dark in every frame. ``lo``,
   the minimum, serves the overlays; the colour maximum the coloured border lines.
2. *bars*, one image side at a time, at full resolution: outermost lines that are uniform
   and saturated are peeled first (a burnt-in coloured frame border); then, within the band
   reaching 35 % into the image, the run length D of dark pixels (below half-way between
   the outermost line's median and the band's bright Otsu class) at each position along the
   side. The bar's depth d is D's mode; it is a bar when D is within +-2 px of d at 20 % of
   the positions and shorter at most at 30 % (dark content beyond a bar makes the run
   longer, only text in the bar shorter), bar and outermost line are at most 40 % of the
   content beyond, the step is at least `region.circle.MIN_STEP`, the outer line flat, the
   edge's 10-90 % ramp at most `BAR_MAX_RAMP_PX` (blanking is sharp; a soft edge is
   shading) and a bar deeper than 5 % of the image is matched on the opposite side within
   20 % (letterboxing is symmetric). Its edge is the median sub-pixel 50 % crossing.
3. *circle* inside the rectangle the bars leave (`region.circle.detect_circle`).
4. *margins*: each detected boundary moves inward by 2 sigma_edge + 1 px, sigma_edge =
   ramp / 2.563 (the 10-90 % width of a Gaussian-blurred step), so the ramp counts as
   outside; a circle the bars cut becomes a polygon (circle ∩ bar rectangle).
5. *static overlays* (3 frames or more, a scene that moves): pixels whose temporal range
   is at most `STATIC_RANGE` grey levels, grouped, near the boundary, with sharp strokes,
   in a moving surround, become holes.

Pixels: (0, 0) is the centre of the top-left pixel (`region`).

Example
-------
>>> import numpy as np
>>> img = np.full((240, 320), 120, np.uint8); img[:30] = 2; img[-30:] = 2    # letterboxed: edges at 29.5, 210.5
>>> reg = detect_valid_region([img])
>>> reg.kind, [round(v, 1) for v in np.array(reg.to_dict()["polygon"])[:, 1].tolist()]
('letterbox', [31.1, 31.1, 207.9, 207.9])
"""
from __future__ import annotations

import math
import time

import numpy as np

from pencilcal.toolkit.detect.region.valid import ValidRegion, circle_polygon, clip_polygon_to_rect, read_mask_file
from pencilcal.toolkit.detect.region.circle import MIN_STEP, detect_circle, edge_ramp
from pencilcal.toolkit.errors import InputError

__all__ = ["MAX_FRAMES", "detect_valid_region", "sequence_region", "sample_indices"]

#: Frames a sequence's region is detected from, sampled evenly across it.
MAX_FRAMES = 16
BAR_MAX_RAMP_PX = 8.0  # a letterbox edge is digital: its 10-90 % ramp is at most this [px]
_BAR_DEPTH_TOL = 2  # [px] a bar's dark run ends within this of its depth ...
_BAR_NEAR = 0.2  # ... at this fraction of the positions along the side at least
_BAR_SHORT = 0.3  # at most this fraction of the runs end short of it (text in the bar)
_BAR_REL_DARK = 0.4  # bar and outermost line at most this fraction of the content beyond
_BAR_BAND = 0.35  # the band searched for a bar reaches this fraction into the image
_UNPAIRED_DEPTH = 0.05  # a bar deeper than this fraction of the image needs its opposite
_RAMP_TO_SIGMA = 2.563  # 10-90 % width of a Gaussian-blurred step, in sd
STATIC_RANGE = 2  # [grey levels] an overlay is identical in every frame up to compression
_MOVING_RANGE = 16.0  # [grey levels] median temporal range of a scene whose overlays can be told
_SIDES = ("top", "bottom", "left", "right")


# ============================================================================ frames


def _prepare_frames(frames, max_frames):
    """Up to max_frames (H, W[, C]) uint8 frames sampled evenly; InputError for bad ones."""
    if isinstance(frames, np.ndarray):
        one = frames.ndim == 2 or (frames.ndim == 3 and frames.shape[2] in (3, 4))
        frames = [frames] if one else list(frames)
    else:
        frames = list(frames)
    if not frames:
        raise InputError("detect_valid_region: no frames")
    shp = None
    for i, f in enumerate(frames):
        f = np.asarray(f)
        if f.dtype != np.uint8:
            raise InputError(f"detect_valid_region: frame {i} has dtype {f.dtype}, expected uint8")
        if f.ndim not in (2, 3) or (f.ndim == 3 and f.shape[2] not in (1, 3, 4)):
            raise InputError(f"detect_valid_region: frame {i} has shape {f.shape}, expected (H, W) or (H, W, 3)")
        if shp is None:
            shp = f.shape[:2]
        elif f.shape[:2] != shp:
            raise InputError(f"detect_valid_region: frame {i} is {f.shape[:2]}, frame 0 is {shp}")
    if len(frames) > max_frames:
        frames = [frames[i] for i in sample_indices(len(frames), max_frames)]
    return [np.asarray(f) for f in frames]


def sample_indices(n, k=MAX_FRAMES):
    """Up to k indices (ascending) spread evenly over n frames, the first and last included.

    >>> sample_indices(100, 4).tolist(), sample_indices(3).tolist()
    ([0, 33, 66, 99], [0, 1, 2])
    """
    return np.unique(np.round(np.linspace(0, n - 1, min(n, k))).astype(int))


def _brightness_stack(frames):
    """Per-pixel maximum and minimum (H, W) uint8 over the frames of the channel-maximum
    brightness, and the colour maximum (H, W, 3)."""
    import cv2

    hi = lo = hic = None
    grey = True  # grey frames only: their colour maximum is hi's three channels, made once
    for f in frames:
        if f.ndim == 3 and f.shape[2] >= 3:
            c = np.ascontiguousarray(f[..., :3])
            b0, b1, b2 = cv2.split(c)
            b = cv2.max(cv2.max(b0, b1), b2)
            if grey and hi is not None:
                hic = cv2.merge([hi, hi, hi])
            grey = False
        else:
            b = np.ascontiguousarray(f if f.ndim == 2 else f[..., 0])
            c = None if grey else cv2.merge([b, b, b])
        if hi is None:
            hi, lo, hic = b.copy(), b.copy(), (None if c is None else c.copy())
        else:
            hi, lo = cv2.max(hi, b), cv2.min(lo, b)
            hic = hic if c is None else cv2.max(hic, c)
    if grey:
        hic = cv2.merge([hi, hi, hi])
    return hi, lo, hic


def _line_noise(v):
    """Robust noise sd of a 1-D signal from adjacent differences (MAD), floored for
    quantised data by the RMS of the small differences."""
    d = np.diff(v.astype(np.float32))
    if d.size < 4:
        return 1.0
    mad = float(np.median(np.abs(d)))
    small = d[np.abs(d) <= max(3.0 * 1.4826 * mad, 2.0)]
    rms = float(np.sqrt(np.mean(small**2))) if small.size else 0.0
    return max(1.4826 * mad, rms) / math.sqrt(2.0)


def _side_view(a, side):
    """View of a (H, W[, C]) array with axis 0 the depth from the given image side."""
    if side == "top":
        return a
    if side == "bottom":
        return a[::-1]
    if side == "left":
        return a.swapaxes(0, 1)
    return a[:, ::-1].swapaxes(0, 1)


# ============================================================================ bars


def _peel_coloured(Cv, e):
    """How many outermost lines of a side (Cv: depth x position x 3 colour maximum) are a
    coloured frame border: uniform (90 % within max(8, 4 sd) of the median colour),
    saturated ((max - min) / max >= 0.5, max >= 32), and clearly unlike the content 2 px
    further in (else it is uniform content: a green screen)."""
    depth_len, pos_len = Cv.shape[:2]
    kmax = max(2, int(round(0.01 * depth_len)))
    peel = 0
    while peel < kmax:
        line = Cv[peel, e:pos_len - e].astype(np.int16)
        med = np.median(line, axis=0)
        dev = np.abs(line - med[None, :]).max(axis=1)
        sig = max(_line_noise(line[:, int(np.argmax(med))]), 1.0)
        uniform = float(np.mean(dev <= max(8.0, 4.0 * sig))) >= 0.9
        mx, mn = float(med.max()), float(med.min())
        if not (uniform and mx >= 32 and (mx - mn) >= 0.5 * mx):
            break
        peel += 1
    if peel == 0:
        return 0
    if peel >= kmax:
        return 0
    inside = np.median(Cv[min(depth_len - 1, peel + 2), e:pos_len - e].astype(np.float32), axis=0)
    edge_c = np.median(Cv[peel - 1, e:pos_len - e].astype(np.float32), axis=0)
    return 0 if float(np.abs(edge_c - inside).max()) < max(24.0, 0.25 * float(edge_c.max())) else peel


def _dark_runs(A, peel, e):
    """The band searched for a bar: (band (depth, positions) uint8, outermost level, the
    dark threshold, the bright level, run lengths D (positions,) of dark pixels from the
    edge (the band's depth where it is all dark))."""
    import cv2

    depth_len, pos_len = A.shape
    maxd = max(peel + 4, int(_BAR_BAND * depth_len))
    bandv = A[peel:maxd, e:pos_len - e]
    level = float(np.median(bandv[0]))
    t_otsu, _ = cv2.threshold(np.ascontiguousarray(bandv), 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    bright = bandv[bandv > t_otsu]
    c_hi = float(np.median(bright)) if bright.size else level
    t_s = level + 0.5 * (c_hi - level)
    band = bandv <= t_s
    D = np.where(band.all(axis=0), band.shape[0], band.argmin(axis=0))
    return bandv, level, t_s, c_hi, D


def _bar_level(bandv, D, d, level, info):
    """The bar's level where its run ends at depth d, or None when the side is no bar: the
    bar and the outermost line dark against the content beyond and flat all along."""
    cap = bandv.shape[0]
    cols = np.nonzero(np.abs(D - d) <= _BAR_DEPTH_TOL)[0]
    o_bar = float(np.median(bandv[:max(1, d - 1), cols]))
    spread = float(np.percentile(bandv[0, cols], 90) - np.percentile(bandv[0, cols], 10))
    c_in = float(np.median(bandv[min(cap - 1, d + 1):min(cap, d + 4), cols]))
    line0 = bandv[0].astype(np.float32)
    spread_all = float(np.percentile(line0, 90) - np.percentile(line0, 10))
    info.update(o_bar=o_bar, c_in=c_in, spread=spread, spread_all=spread_all)
    ok = (c_in - o_bar >= MIN_STEP) and (o_bar <= _BAR_REL_DARK * c_in) and (level <= _BAR_REL_DARK * c_in) and \
        (spread <= 0.5 * (c_in - o_bar)) and (spread_all <= 0.5 * (c_in - level))
    return o_bar if ok else None


def _bar_edge(A, D, d, peel, e, level):
    """The bar's edge [px from the image side, pixel centres] (the median sub-pixel 50 %
    crossing of profiles across it) and its 10-90 % ramp [px]."""
    depth_len = A.shape[0]
    k0 = peel + d
    L = int(max(6, min(2 * d + 4, 24)))
    lo_i, hi_i = peel, min(depth_len, k0 + L)
    cols = np.nonzero(np.abs(D - d) <= _BAR_DEPTH_TOL)[0] + e
    seg = A[lo_i:hi_i, cols].astype(np.float32).T[:, ::-1]  # outward profiles
    s = (k0 - 0.5) - np.arange(lo_i, hi_i, dtype=float)[::-1]  # outward offset
    q = max(1, min(3, (hi_i - k0) // 2))
    in_lvl = np.median(seg[:, :q], axis=1)
    out_lvl = np.full(len(seg), level)
    good = (in_lvl - out_lvl >= MIN_STEP) & (out_lvl <= 0.5 * in_lvl)
    if good.sum() < max(5, 0.1 * len(seg)):
        return k0 - 0.5, 1.0
    s50, s10, s90 = edge_ramp(seg[good], s, out_lvl[good], in_lvl[good])
    okk = np.isfinite(s50)
    return (k0 - 0.5) - float(np.median(s50[okk])), float(np.median((s10 - s90)[okk]))


def _side_bar(hi, hic, side, min_bar_px):
    """The bar of one image side: {edge, ramp, depth, peel, level, dim} or None, and
    diagnostics (module docstring, step 2)."""
    A, Cv = _side_view(hi, side), _side_view(hic, side)
    depth_len, pos_len = A.shape
    e = max(1, int(0.03 * pos_len))
    peel = _peel_coloured(Cv, e)
    info = {"peel": peel}
    bandv, level, t_s, c_hi, D = _dark_runs(A, peel, e)
    info.update(level=level, c_hi=c_hi, t=round(t_s, 1))
    line_only = dict(edge=peel - 0.5, ramp=0.0, depth=0, peel=peel, level=level, dim=depth_len) if peel else None
    if c_hi - level < MIN_STEP:
        info["why"] = "no contrast"
        return line_only, info
    P = D[D < bandv.shape[0]]
    if P.size < 0.3 * D.size:
        info["why"] = "side mostly dark (no straight edge)"
        return line_only, info
    d = int(np.argmax(np.bincount(P, minlength=bandv.shape[0] + 1)))
    near = float(np.mean(np.abs(P - d) <= _BAR_DEPTH_TOL))
    short = float(np.mean(P < d - _BAR_DEPTH_TOL))
    info.update(mode=d, near=round(near, 3), short=round(short, 3))
    o_bar = _bar_level(bandv, D, d, level, info) if d >= 1 and near >= _BAR_NEAR and short <= _BAR_SHORT else None
    if o_bar is None:
        info["why"] = "no consistent dark band with a straight edge"
        return line_only, info
    edge, ramp = _bar_edge(A, D, d, peel, e, o_bar)
    if edge + 0.5 < min_bar_px and peel == 0:
        info["why"] = "thinner than min_bar_px"
        return None, info
    info["ramp"] = round(ramp, 2)
    if ramp > BAR_MAX_RAMP_PX:
        info["why"] = "edge too soft for a bar"
        return line_only, info
    return dict(edge=edge, ramp=ramp, depth=d, peel=peel, level=o_bar, dim=depth_len), info


def _detect_bars(hi, hic, min_bar_px):
    """Letterbox / pillarbox bars: {side: {edge [px from that side], ramp [px], ...}} and
    diagnostics per side."""
    out, diag = {}, {}
    for side in _SIDES:
        bar, diag[side] = _side_bar(hi, hic, side, min_bar_px)
        if bar is not None:
            out[side] = bar
    # letterboxing is symmetric: an unpaired bar deeper than 5 % of the image is more likely
    # a dark scene region with a straight edge
    reject = set()
    for a, b in (("top", "bottom"), ("bottom", "top"), ("left", "right"), ("right", "left")):
        if a in out and out[a].get("depth", 0) > _UNPAIRED_DEPTH * out[a]["dim"]:
            ea, eb = out[a]["edge"], out[b]["edge"] if b in out else -1.0
            if abs(ea - eb) > max(3.0, 0.2 * ea):
                diag[a]["why"] = "unpaired bar deeper than 5 % of the image"
                reject.add(a)
    return {k: v for k, v in out.items() if k not in reject}, diag


# ============================================================================ overlays


def _static_overlays(hi, lo, reg, sigma):
    """Holes (x0, y0, x1, y1) [px] over static burnt-in overlays (text, logos) inside the
    region near its boundary (module docstring, step 5), and diagnostics."""
    import cv2

    H, W = hi.shape
    valid = reg.mask()
    rng_ = cv2.subtract(hi, lo)
    if valid.sum() < 1000:
        return [], {}
    n_t = float(np.median(rng_[valid]))
    diag = {"temporal_median_range": n_t}
    if n_t < _MOVING_RANGE:
        diag["why"] = "scene too static to tell overlays from content"
        return [], diag
    static = (valid & (rng_ <= STATIC_RANGE) & (hi < 250)).astype(np.uint8)
    static = cv2.morphologyEx(static, cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))
    k = max(3, int(round(0.006 * max(H, W))))
    block = cv2.dilate(static, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * k + 1, 2 * k + 1)))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(block, connectivity=8)
    grad = cv2.magnitude(cv2.Sobel(hi, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(hi, cv2.CV_32F, 0, 1, ksize=3)) / 8.0
    holes = []
    for i in range(1, n):
        x, y, w, h, _ = (int(v) for v in stats[i])
        npx = int((static[y:y + h, x:x + w].astype(bool) & (lab[y:y + h, x:x + w] == i)).sum())
        if w * h > 0.05 * H * W or npx < 20:
            continue
        xa, ya, xb, yb = max(0, x - 2 * k), max(0, y - 2 * k), min(W, x + w + 2 * k), min(H, y + h + 2 * k)
        ring = np.ones((yb - ya, xb - xa), bool)
        ring[y - ya:y - ya + h, x - xa:x - xa + w] = False
        ring &= valid[ya:yb, xa:xb]
        ring_rng = float(np.median(rng_[ya:yb, xa:xb][ring])) if ring.any() else 0.0
        corners = np.array([[x, y], [x + w - 1, y], [x, y + h - 1], [x + w - 1, y + h - 1]], float)
        dmin = float(reg.distance_to_boundary(corners).min())
        gq = float(np.percentile(grad[y:y + h, x:x + w], 90))
        # near the boundary, sharp strokes, the scene around it moving
        if dmin <= 0.2 * min(H, W) and gq >= max(8.0, 6.0 * sigma) and ring_rng >= 0.5 * n_t:
            holes.append((float(x - k), float(y - k), float(x + w - 1 + k), float(y + h - 1 + k)))
    return holes, diag


# ============================================================================ the region


def _margin(ramp, margin_px):
    """How far [px] a boundary moves inward: `margin_px`, or 2 sigma_edge + 1 from its ramp."""
    return float(margin_px) if margin_px is not None else 2.0 * max(float(ramp), 0.0) / _RAMP_TO_SIGMA + 1.0


def _content_rect(bars, W, H):
    """(x0, y0, x1, y1) [px]: the rectangle the bars' 50 % edges leave."""
    x0 = bars["left"]["edge"] if "left" in bars else 0.0
    x1 = (W - 1) - bars["right"]["edge"] if "right" in bars else W - 1.0
    y0 = bars["top"]["edge"] if "top" in bars else 0.0
    y1 = (H - 1) - bars["bottom"]["edge"] if "bottom" in bars else H - 1.0
    return max(0.0, x0), max(0.0, y0), min(W - 1.0, x1), min(H - 1.0, y1)


def _assemble(W, H, bars, rect, circle, bm, cm, info):
    """The eroded region (module docstring, step 4): each bar edge moved in by its margin
    bm[side], the circle's radius by cm; a circle the bars cut becomes a polygon."""
    x0, y0, x1, y1 = rect
    ex0 = x0 + bm["left"] if "left" in bars else 0.0
    ex1 = x1 - bm["right"] if "right" in bars else W - 1.0
    ey0 = y0 + bm["top"] if "top" in bars else 0.0
    ey1 = y1 - bm["bottom"] if "bottom" in bars else H - 1.0
    if ex1 <= ex0 or ey1 <= ey0:
        info["why"] = "bars leave no content; returning the full frame"
        return ValidRegion(W, H, polygon=ValidRegion.full(W, H).polygon, kind="full", info=info)
    if circle is not None:
        cx, cy, r50 = circle
        rr = r50 - cm
        info["circle_50"] = [cx, cy, r50]
        clip = (("left" in bars and ex0 > cx - rr) or ("right" in bars and ex1 < cx + rr)
                or ("top" in bars and ey0 > cy - rr) or ("bottom" in bars and ey1 < cy + rr))
        if not clip:
            return ValidRegion(W, H, circle=(cx, cy, rr), kind="circle", info=info)
        poly = clip_polygon_to_rect(circle_polygon(cx, cy, rr), (ex0, ey0, ex1, ey1))
        return ValidRegion(W, H, polygon=tuple(map(tuple, poly.tolist())), kind="polygon", info=info)
    if bars:
        return ValidRegion.from_rect(ex0, ey0, ex1, ey1, W, H, kind="letterbox", info=info)
    return ValidRegion(W, H, polygon=ValidRegion.full(W, H).polygon, kind="full", info=info)


def detect_valid_region(frames, *, max_frames=MAX_FRAMES, work_size=640, margin_px=None, detect_overlays=True,
                        min_bar_px=1.0, seed=0):
    """The valid region of a sequence from one or more of its frames (module docstring).

    Parameters
    ----------
    frames : sequence of (H, W) or (H, W, 3) uint8 arrays, or one array
        Frames of one sequence (any channel order); up to `max_frames` are sampled evenly.
    work_size : int
        Longer side [px] of the working image of the circle search.
    margin_px : float, optional
        How far every detected boundary moves inward [px]; default 2 sigma_edge + 1 from
        each boundary's own ramp (the image border never moves).
    detect_overlays : bool
        Static overlays become holes (3 frames or more).
    min_bar_px : float
        Bars thinner than this [px] are ignored.
    seed : int
        Seed of the circle search's RANSAC (the result is deterministic).

    Returns
    -------
    ValidRegion
        Conservative: the boundaries moved inward by their margins. ``info`` holds the
        un-eroded fit (``circle_50``, ``bars``), the margins and per-step diagnostics.
    """
    t0 = time.perf_counter()
    fr = _prepare_frames(frames, max_frames)
    H, W = fr[0].shape[:2]
    hi, lo, hic = _brightness_stack(fr)
    info = {"n_frames": len(fr), "size": [W, H]}
    bars, info["bars_diag"] = _detect_bars(hi, hic, min_bar_px)
    info["bars"] = {k: round(v["edge"], 2) for k, v in bars.items()}
    rect = _content_rect(bars, W, H)
    circle = circle_ramp = None
    if rect[2] - rect[0] > 32 and rect[3] - rect[1] > 32:
        (circle, circle_ramp), info["circle_diag"] = detect_circle(hi, rect, work_size, np.random.default_rng(seed))
    bm = {k: _margin(v["ramp"], margin_px) for k, v in bars.items()}
    cm = _margin(circle_ramp, margin_px) if circle is not None else None
    info.update(margin_bars={k: round(v, 2) for k, v in bm.items()}, margin_circle=cm,
                margin=max([cm or 0.0] + list(bm.values())) if (bars or circle is not None) else 0.0)
    reg = _assemble(W, H, bars, rect, circle, bm, cm, info)
    if detect_overlays and len(fr) >= 3:
        holes, info["overlay_diag"] = _static_overlays(hi, lo, reg, 1.0)
        if holes:
            reg = ValidRegion(reg.width, reg.height, circle=reg.circle, polygon=reg.polygon, holes=tuple(holes),
                              kind=reg.kind, info=info)
    info["time_s"] = round(time.perf_counter() - t0, 4)
    return reg


def _as_u8(image):
    """A frame as uint8 (16-bit and float frames stretched as the detectors see them)."""
    from pencilcal.toolkit.detect.image import to_u8

    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img
    if img.ndim == 3:
        return np.stack([to_u8(img[..., c]) for c in range(img.shape[2])], -1)
    return to_u8(img)


# a video of fewer frames than this per sampled frame gives its first frames, read ahead for
# the run, instead of frames sought across it
_SEQUENTIAL_FRAMES_PER_SAMPLE = 8


def _sampled_frames(source, k):
    """Up to k decodable frames (arrays of one size) spread evenly over an ImageSource."""
    from pencilcal.toolkit.io.images import decode_image

    n = len(source)
    want = set(sample_indices(n, k).tolist()) if n > 0 else None
    out = []
    if source.kind == "video" and (not want or max(want) < _SEQUENTIAL_FRAMES_PER_SAMPLE * k):
        # a short video (or one without a frame count): its first k frames, kept for the run
        # (sampling them across it would decode the whole video a second time)
        out = source.head(k)
    elif source.kind == "images":
        for i in sorted(want or ()):
            img, _ = decode_image(source.paths[i], gray=source.gray, max_pixels=source.max_pixels)
            if img is not None:
                out.append(img)
    else:
        out = _video_frames(source, want, k)
    shape = out[0].shape[:2] if out else None
    return [_as_u8(f) for f in out if f.shape[:2] == shape]


def _video_frames(source, want, k):
    """The frames at indices `want` of a long video source (seeking; the container's count
    may be off: where seeking fails, the first k frames)."""
    import cv2

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    cap = cv2.VideoCapture(str(source.paths[0]))
    out = []
    try:
        for i in sorted(want or ()):
            if cap.set(cv2.CAP_PROP_POS_FRAMES, int(i)):
                ok, img = cap.read()
                if ok and img is not None:
                    out.append(img)
    finally:
        cap.release()
    if out:
        return [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) if source.gray and f.ndim == 3 else f for f in out]
    return source.head(k)


def sequence_region(source, mask_path=None, shape=None, max_frames=MAX_FRAMES):
    """The valid region the detectors use on the frames of a sequence.

    Parameters
    ----------
    source : ImageSource
        The sequence (`toolkit.io.images.open_images`).
    mask_path : str or Path, optional
        A user's mask (`region.read_mask_file`: a PNG, or JSON/YAML with a circle or a
        polygon) instead of detecting the region.
    shape : (H, W), optional
        The frames' size (the camera's); default that of the first frame that decodes.
    max_frames : int
        The region is detected from up to this many frames sampled evenly across the
        sequence (`detect_valid_region`; ~0.02 s a frame); from a video shorter than
        `_SEQUENTIAL_FRAMES_PER_SAMPLE` x max_frames, its first ones, read ahead and kept
        for the run (the source's next iteration yields them first) instead of decoding
        the video twice.

    Returns
    -------
    ValidRegion or None
        None when no frame decodes (and no mask file is given with a shape).
    """
    frames = [] if mask_path is not None and shape is not None else _sampled_frames(source, max_frames)
    if shape is None and frames:
        shape = frames[0].shape[:2]
    if mask_path is not None:
        return None if shape is None else read_mask_file(mask_path, shape)
    frames = [f for f in frames if shape is None or f.shape[:2] == tuple(shape)]
    return detect_valid_region(frames) if frames else None
