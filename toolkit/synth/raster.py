"""Exact-area rasterisation of polygons, and the camera side: clipping, projection, rays.

Every geometric edge in a rendered frame is the image of a straight 3D segment. Each
polygon is clipped in 3D against the camera's viewing volume (`view_planes`: the planes
through the camera centre bounding the back-projected image border, and a near plane), its
edges are subdivided until every chord is at most 1 px long in the image and projected with
`Camera.project` (exact for every lens model, fisheye included), and the resulting outlines
are scan-converted with *exact area coverage* (`coverage`): the signed-area accumulation
rasteriser used by font renderers (the trapezoid under every piece of every edge inside
every pixel, then a running sum along rows). A pixel's value is therefore the box-filter
average of the scene over its square, as a sensor with 100 % fill factor integrates it, up
to the chord error of the 1 px subdivision. Measured edge positions agree with the
projected truth to 1e-11 px (pinhole), 1e-5 px (strong opencv distortion) and 1e-4 px
(fisheye) (tests/toolkit/synth/test_raster.py), far inside a 0.05 px budget.

Shading needs a viewing ray per pixel (`pixel_rays`): those are interpolated (bicubic,
8 px grid) from exact `Camera.rays_from_pixels` values; they only colour surfaces, the
geometry of every edge comes from the exact forward projection. View planes and rays are
computed once per camera and kept for the last few cameras (functools.lru_cache, keyed by
the camera's exact parameters).

Conventions: OpenCV camera frame and pixels (pixel (0, 0) is the centre of the top-left
pixel, which covers [-0.5, 0.5] x [-0.5, 0.5]); lengths in the target's unit (mm).

Example
-------
>>> tri = np.array([[-0.5, -0.5], [1.5, -0.5], [-0.5, 1.5]])          # half of a 2 x 2 px box
>>> polygon_coverage([(tri, 1)], 2, 2).tolist()
[[1.0, 0.5], [0.5, 0.0]]
"""
from __future__ import annotations

import functools

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.synth.polygons import convex_hull, signed_area

__all__ = ["coverage", "polygon_coverage", "pixel_rays", "view_planes", "render_coverage", "target_coverage",
           "to_camera"]

# Longest chord [px] of a subdivided edge under a distorting lens; the chord's sagitta
# L^2 / (8 R) stays below 1e-3 px for the radii of curvature (> 150 px) lenses give.
_MAX_CHORD_PX = 1.0
# Pixels beyond the image border that the clipping volume keeps (so border pixels see
# their whole neighbourhood), and the step of the border samples that define it.
_CLIP_MARGIN_PX = 4.0
_CLIP_STEP_PX = 16.0
# Rays further than this off the optical axis are not rendered: polygons are clipped in
# normalised coordinates, which end at 90 deg (fisheye lenses can see beyond; those pixels
# show the backdrop's wall).
_MAX_RAY_ANGLE = np.radians(89.5)
_NEAR = 1e-3  # near clipping plane [target units]
# Step [px] of the grid of exact rays that `pixel_rays` interpolates.
_RAY_GRID_PX = 8


def coverage(x0, y0, x1, y1, weight, width, height):
    """Exact area coverage of pixels by closed outlines given as directed edges.

    The signed-area accumulation rasteriser: each edge piece inside a pixel adds the
    trapezoid between it and the pixel's right side; a running sum along each row turns
    that into the area of the outlines inside every pixel. Exact for straight edges;
    independent of the order of the edges.

    Parameters
    ----------
    x0, y0, x1, y1 : (E,) array_like
        Edge end points [pixels, OpenCV convention: pixel (0, 0) is the centre of the
        top-left pixel, which covers [-0.5, 0.5] x [-0.5, 0.5]].
    weight : (E,) array_like
        +1 for edges of a polygon with positive signed area that is to be filled (in
        pixel coordinates, x right, y down), -1 to subtract; any real weight works.
    width, height : int
        Image size [pixels].

    Returns
    -------
    (height, width) ndarray
        Covered fraction of every pixel (the weighted area of the outlines inside it).

    Example
    -------
    >>> sq = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])   # 2 x 1 px box
    >>> a, b = sq, np.roll(sq, -1, 0)
    >>> coverage(a[:, 0], a[:, 1], b[:, 0], b[:, 1], np.ones(4), 3, 2).round(3).tolist()
    [[0.25, 0.5, 0.25], [0.25, 0.5, 0.25]]
    """
    W, H = int(width), int(height)
    cov, (r0, c0) = _coverage_window(x0, y0, x1, y1, weight, W, H)
    out = np.zeros((H, W))
    out[r0:r0 + cov.shape[0], c0:c0 + cov.shape[1]] = cov
    return out


def _coverage_window(x0, y0, x1, y1, weight, W, H):
    """`coverage` restricted to the rows and columns the outlines touch.

    Returns (cov, (row0, col0)): cov (h, w) is the coverage of the image window starting
    at (row0, col0); outside it the coverage is zero.
    """
    seg = np.stack([np.asarray(x0, float), np.asarray(y0, float), np.asarray(x1, float),
                    np.asarray(y1, float), np.broadcast_to(np.asarray(weight, float), np.shape(x0))], -1)
    seg = seg.reshape(-1, 5) + np.array([0.5, 0.5, 0.5, 0.5, 0.0])  # pixel cells [c, c+1)
    seg = seg[np.all(np.isfinite(seg), axis=1) & (seg[:, 1] != seg[:, 3]) & (seg[:, 4] != 0)]
    # rows outside the image never show: clip in y; columns right of it neither
    seg = _split_at(seg, 1, 0.0)
    seg = _split_at(seg, 1, float(H))
    ym = (seg[:, 1] + seg[:, 3]) / 2.0
    seg = seg[(ym > 0) & (ym < H)]
    seg = _split_at(seg, 0, 0.0)
    seg = _split_at(seg, 0, float(W))
    xm = (seg[:, 0] + seg[:, 2]) / 2.0
    seg = seg[xm < W]
    if len(seg) == 0:
        return np.zeros((0, 0)), (0, 0)
    # left of the image only an edge's vertical extent matters: collapse it to one column
    left = xm[xm < W] < 0
    seg[left, 0] = -0.5
    seg[left, 2] = -0.5
    xa, ya, xb, yb, w = _pieces(seg)
    col = np.floor((xa + xb) / 2.0)
    row = np.floor((ya + yb) / 2.0).astype(np.int64)
    frac = (xa + xb) / 2.0 - col
    area = w * (ya - yb)  # positive-area outlines give positive coverage
    ok = (row >= 0) & (row < H) & (area != 0)
    if not np.any(ok):
        return np.zeros((0, 0)), (0, 0)
    col = np.maximum(col.astype(np.int64)[ok], -1)
    row, frac, area = row[ok], frac[ok], area[ok]
    # window: rows touched; columns from the leftmost piece to the rightmost (the running
    # sum is back to zero right of the last edge of closed outlines)
    r0, r1 = int(row.min()), int(row.max()) + 1
    c0, c1 = max(int(col.min()), 0), min(int(col.max()) + 2, W)
    ww = c1 - c0 + 2  # column 0 of acc collects everything left of the window
    idx = (row - r0) * ww + np.clip(col - c0 + 1, 0, ww - 1)
    idx2 = (row - r0) * ww + np.clip(col - c0 + 2, 0, ww - 1)
    n = (r1 - r0) * ww
    acc = np.bincount(idx, area * (1.0 - frac), minlength=n)[:n]
    acc += np.bincount(idx2, area * frac, minlength=n)[:n]
    cov = np.cumsum(acc.reshape(r1 - r0, ww), axis=1)[:, 1:1 + c1 - c0]
    if c1 < W and np.any(np.abs(cov[:, -1]) > 1e-12):
        # outlines closed right of the image (edges dropped above): the running sum
        # stays constant from the last piece to the image's right border
        cov = np.concatenate([cov, np.repeat(cov[:, -1:], W - c1, axis=1)], axis=1)
    return cov, (r0, c0)


def _split_at(seg, axis, value):
    """Split segments (N, 5) that cross coordinate `axis` == value into two."""
    a, b = seg[:, axis], seg[:, 2 + axis]
    cross = (a - value) * (b - value) < 0
    if not np.any(cross):
        return seg
    s = seg[cross]
    t = (value - s[:, axis]) / (s[:, 2 + axis] - s[:, axis])
    mid = s[:, 0:2] + t[:, None] * (s[:, 2:4] - s[:, 0:2])
    mid[:, axis] = value
    first, second = s.copy(), s.copy()
    first[:, 2:4] = mid
    second[:, 0:2] = mid
    return np.concatenate([seg[~cross], first, second])


def _pieces(seg):
    """Split segments at every integer x and y so each piece lies inside one pixel cell."""
    n = len(seg)
    x0, y0, x1, y1, w = seg.T
    ids, ts = [np.arange(n), np.arange(n)], [np.zeros(n), np.ones(n)]
    for a, b in ((x0, x1), (y0, y1)):
        lo = np.floor(np.minimum(a, b))
        hi = np.ceil(np.maximum(a, b))
        cnt = np.maximum(hi - lo - 1, 0).astype(np.int64)
        total = int(cnt.sum())
        if total:
            idx = np.repeat(np.arange(n), cnt)
            k = np.repeat(lo, cnt) + 1 + (np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt))
            ids.append(idx)
            ts.append((k - a[idx]) / (b[idx] - a[idx]))
    ids = np.concatenate(ids)
    ts = np.concatenate(ts)
    order = np.lexsort((ts, ids))
    ids, ts = ids[order], ts[order]
    same = ids[1:] == ids[:-1]
    sid, ta, tb = ids[:-1][same], ts[:-1][same], ts[1:][same]
    dx, dy = (x1 - x0)[sid], (y1 - y0)[sid]
    return x0[sid] + ta * dx, y0[sid] + ta * dy, x0[sid] + tb * dx, y0[sid] + tb * dy, w[sid]


def polygon_coverage(polygons, width, height):
    """Exact pixel coverage of polygons given in pixel coordinates.

    polygons: iterable of ((N, 2) array, sign): sign +1 fills the polygon, -1 removes it
    (a hole), whatever the polygon's orientation. Returns (height, width) float.

    Example
    -------
    >>> polygon_coverage([(np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5]]), 1)], 2, 1).tolist()
    [[0.5, 0.0]]
    """
    a, b, w = [], [], []
    for poly, sign in polygons:
        p = np.asarray(poly, float)
        if len(p) < 3:
            continue
        area = signed_area(p)
        if area == 0 or not np.isfinite(area):
            continue
        a.append(p)
        b.append(np.roll(p, -1, axis=0))
        w.append(np.full(len(p), float(sign) * np.sign(area)))
    if not a:
        return np.zeros((int(height), int(width)))
    a, b, w = np.concatenate(a), np.concatenate(b), np.concatenate(w)
    return coverage(a[:, 0], a[:, 1], b[:, 0], b[:, 1], w, width, height)


def pixel_rays(camera):
    """(H, W, 3) float32 unit viewing rays of every pixel (camera frame), read-only.

    Exact rays on an 8 px grid, bicubic in between: used only for shading and textures.
    NaN where the lens model has no ray. Computed once per camera (the last few cameras'
    rays are kept, keyed by their exact parameters).
    """
    return _cached_rays(_camera_key(camera), camera)


def _camera_key(camera):
    """The exact parameters of a camera as a hashable tuple (bytes, so 0.0 and -0.0 differ)."""
    return (camera.model, camera.width, camera.height, camera.K.tobytes(), camera.dist.tobytes())


@functools.lru_cache(maxsize=8)
def _cached_rays(key, camera):
    """`pixel_rays` of `camera`; `key` (`_camera_key`) is what the cache tells cameras apart by."""
    import cv2

    W, H = camera.width, camera.height
    g = _RAY_GRID_PX
    us = np.arange(0, W - 1 + 2 * g, g, dtype=float)
    vs = np.arange(0, H - 1 + 2 * g, g, dtype=float)
    uu, vv = np.meshgrid(us, vs)
    r = camera.rays_from_pixels(np.stack([uu, vv], -1))
    grid = np.nan_to_num(r, nan=0.0).astype(np.float32)
    mx = (np.arange(W, dtype=np.float32) / g)[None, :].repeat(H, 0)
    my = (np.arange(H, dtype=np.float32) / g)[:, None].repeat(W, 1)
    rays = cv2.remap(grid, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    n = np.linalg.norm(rays, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        rays = rays / n
    bad = cv2.remap(np.isnan(r[..., 0]).astype(np.float32), mx, my, cv2.INTER_LINEAR) > 0
    rays[bad | ~(n[..., 0] > 0.5)] = np.nan
    rays.setflags(write=False)
    return rays


def view_planes(camera):
    """Half-spaces N . X + d >= 0 (camera frame) bounding what the image can show.

    (P, 4) read-only float array, rows (Nx, Ny, Nz, d) [d in target units]; computed once
    per camera (`_view_planes_of`, cached like `pixel_rays`).

    Example
    -------
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("pinhole", 4, 2, [[100.0, 0, 1.5], [0, 100.0, 0.5], [0, 0, 1]])
    >>> view_planes(cam)[0].tolist()                      # the near plane z >= 1e-3
    [0.0, 0.0, 1.0, -0.001]
    """
    return _cached_view_planes(_camera_key(camera), camera)


@functools.lru_cache(maxsize=8)
def _cached_view_planes(key, camera):
    """`view_planes` of `camera`, keyed by `key` (`_camera_key`)."""
    planes = _view_planes_of(camera)
    planes.setflags(write=False)
    return planes


def _view_planes_of(camera):
    """Half-spaces N . X + d >= 0 (camera frame) bounding what the image can show.

    The back-projected image border (expanded by a few pixels) in normalised coordinates,
    its convex hull, and the planes through the camera centre along the hull's edges;
    plus a near plane. Inside them the lens model is used only where it is invertible,
    so no polygon folds back into the image from beyond the valid field of view.
    Returns (P, 4): rows (Nx, Ny, Nz, d).
    """
    W, H = camera.width, camera.height
    m = _CLIP_MARGIN_PX
    x0, x1, y0, y1 = -0.5 - m, W - 0.5 + m, -0.5 - m, H - 0.5 + m
    nx = int(np.ceil((x1 - x0) / _CLIP_STEP_PX)) + 1
    ny = int(np.ceil((y1 - y0) / _CLIP_STEP_PX)) + 1
    xs, ys = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
    border = np.concatenate([np.stack([xs, np.full(nx, y0)], -1), np.stack([xs, np.full(nx, y1)], -1),
                             np.stack([np.full(ny, x0), ys], -1), np.stack([np.full(ny, x1), ys], -1)])
    rays = camera.rays_from_pixels(border)
    rays = rays[np.all(np.isfinite(rays), axis=1)]
    if len(rays) < 3:
        raise InputError("the camera's lens model cannot be inverted at the image border")
    ang = np.arccos(np.clip(rays[:, 2], -1.0, 1.0))
    over = ang > _MAX_RAY_ANGLE
    if np.any(over):
        xy = rays[over, :2] / np.linalg.norm(rays[over, :2], axis=1, keepdims=True)
        rays[over] = np.concatenate([np.sin(_MAX_RAY_ANGLE) * xy, np.full((over.sum(), 1), np.cos(_MAX_RAY_ANGLE))], 1)
    hull = convex_hull(rays[:, :2] / rays[:, 2:3])
    if len(hull) < 3:
        raise InputError("the camera's field of view is degenerate")
    e = np.roll(hull, -1, axis=0) - hull
    n = np.stack([-e[:, 1], e[:, 0]], -1)  # left of each edge = inside (positive area)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    planes = np.concatenate([n, -np.sum(n * hull, axis=1, keepdims=True), np.zeros((len(n), 1))], 1)
    near = np.array([[0.0, 0.0, 1.0, -_NEAR]])
    return np.concatenate([near, planes])


def _clip_convex(P, planes):
    """Sutherland-Hodgman: polygon P (N, 3) clipped by half-spaces N . X + d >= 0."""
    for Nx, Ny, Nz, d in planes:
        s = P @ np.array([Nx, Ny, Nz]) + d
        if np.all(s >= 0):
            continue
        if np.all(s < 0):
            return None
        P1 = np.roll(P, -1, axis=0)
        s1 = np.roll(s, -1)
        ins0, ins1 = s >= 0, s1 >= 0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(ins0 != ins1, s / (s - s1), 0.0)
        X = P + t[:, None] * (P1 - P)
        cand = np.stack([P, X], 1)
        keep = np.stack([ins0, ins0 != ins1], 1)
        P = cand[keep]
        if len(P) < 3:
            return None
    return P


def _project_polygons(camera, polygons):
    """Pixel-space directed edges of camera-frame polygons, clipped and subdivided.

    polygons: list of ((N, 3) camera-frame vertices, sign). Returns (pa, pb, w): edge
    end points (E, 2) [pixels] and weights (E,) ready for `coverage`.
    """
    planes = view_planes(camera)
    A, B, Wt = [], [], []
    if polygons:
        verts = np.concatenate([p for p, _ in polygons])
        s = verts @ planes[:, :3].T + planes[:, 3]  # (V, P)
        starts = np.cumsum([0] + [len(p) for p, _ in polygons])[:-1]
        all_in = np.minimum.reduceat(s.min(axis=1), starts) >= 0
        any_plane_all_out = np.any(np.maximum.reduceat(s, starts, axis=0) < 0, axis=1)
    for k, (P, sign) in enumerate(polygons):
        if any_plane_all_out[k]:
            continue
        if not all_in[k]:
            P = _clip_convex(P, planes)
            if P is None:
                continue
        xy = P[:, :2] / P[:, 2:3]
        area = signed_area(xy)
        if area == 0 or not np.isfinite(area):
            continue
        A.append(P)
        B.append(np.roll(P, -1, axis=0))
        Wt.append(np.full(len(P), float(sign) * np.sign(area)))
    if not A:
        z = np.zeros((0, 2))
        return z, z, np.zeros(0)
    A, B, Wt = np.concatenate(A), np.concatenate(B), np.concatenate(Wt)
    pa, pb = camera.project(A), camera.project(B)
    if camera.model == "pinhole" or camera.dist.size == 0 or not np.any(camera.dist):
        return pa, pb, Wt  # straight lines stay straight: no subdivision needed
    out_a, out_b, out_w = [], [], []
    for _ in range(16):
        L = np.linalg.norm(pb - pa, axis=1)
        long_ = ~(L <= _MAX_CHORD_PX)
        out_a.append(pa[~long_])
        out_b.append(pb[~long_])
        out_w.append(Wt[~long_])
        if not np.any(long_):
            break
        A, B, Wt, L = A[long_], B[long_], Wt[long_], L[long_]
        n = np.clip(np.ceil(np.nan_to_num(L, nan=2.0) / _MAX_CHORD_PX), 2, 4096).astype(np.int64)
        idx = np.repeat(np.arange(len(A)), n)
        j = np.arange(idx.size) - np.repeat(np.cumsum(n) - n, n)
        t0 = (j / n[idx])[:, None]
        t1 = ((j + 1) / n[idx])[:, None]
        D = B - A
        # each new vertex is projected once and shared by the two chords meeting there
        T = np.concatenate([t0, t1[np.cumsum(n) - 1]])
        I = np.concatenate([idx, np.arange(len(A))])
        proj = camera.project(A[I] + T * D[I])
        pa = proj[:idx.size]
        pb = np.empty_like(pa)
        pb[:-1] = pa[1:]
        last = np.cumsum(n) - 1
        pb[last] = proj[idx.size:]
        A, B, Wt = A[idx] + t0 * D[idx], A[idx] + t1 * D[idx], Wt[idx]
    else:
        raise InputError("edge subdivision did not converge (lens model folds inside the view?)")
    return np.concatenate(out_a), np.concatenate(out_b), np.concatenate(out_w)


def render_coverage(camera, polygons, window=False):
    """Exact pixel coverage of camera-frame polygons, clipped to the view and projected.

    Parameters
    ----------
    camera : Camera
    polygons : list of ((N, 3) array, sign)
        Planar polygons in the camera frame [target units]; sign +1 fills, -1 cuts a hole.
    window : bool
        Return only the part of the image where the coverage may be non-zero.

    Returns
    -------
    (H, W) float ndarray, the covered fraction of every pixel; or with ``window=True``
    ``(cov, (rows, cols))``: cov (h, w) and the two slices of the image it covers (empty
    if nothing shows).
    """
    pa, pb, w = _project_polygons(camera, polygons)
    cov, (r0, c0) = _coverage_window(pa[:, 0], pa[:, 1], pb[:, 0], pb[:, 1], w, camera.width, camera.height)
    if window:
        return cov, (slice(r0, r0 + cov.shape[0]), slice(c0, c0 + cov.shape[1]))
    out = np.zeros((camera.height, camera.width))
    out[r0:r0 + cov.shape[0], c0:c0 + cov.shape[1]] = cov
    return out


def target_coverage(camera, R_cam_from_target, t_cam_from_target, polygons):
    """Exact pixel coverage of polygons in the target frame, as `render_frame` draws them.

    Parameters
    ----------
    camera : Camera
    R_cam_from_target, t_cam_from_target : (3, 3), (3,)
        Pose of the target [mm].
    polygons : iterable of ((N, 2) or (N, 3) array, sign)
        Target-frame vertices [mm] (z = 0 when 2-D); sign +1 fills, -1 cuts a hole.

    Returns
    -------
    (H, W) ndarray
        Covered fraction of every pixel (box filter over the pixel's square).

    Example
    -------
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("pinhole", 4, 2, [[100.0, 0, 1.5], [0, 100.0, 0.5], [0, 0, 1]])
    >>> half = [(np.array([[0.0, -1e3], [1e3, -1e3], [1e3, 1e3], [0.0, 1e3]]), 1)]   # x > 0
    >>> target_coverage(cam, np.eye(3), [0.0, 0.0, 100.0], half).tolist()
    [[0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0]]
    """
    R = np.asarray(R_cam_from_target, float)
    t = np.asarray(t_cam_from_target, float).reshape(3)
    return render_coverage(camera, [(to_camera(R, t, p), s) for p, s in polygons])


def to_camera(R, t, pts2_or_3):
    """Target-frame points (..., 2) (z = 0) or (..., 3) [mm] into the camera frame:
    ``R p + t`` with R (3, 3), t (3,); returns (..., 3) [mm]."""
    p = np.asarray(pts2_or_3, float)
    if p.shape[-1] == 2:
        p = np.concatenate([p, np.zeros(p.shape[:-1] + (1,))], -1)
    return p @ R.T + t
