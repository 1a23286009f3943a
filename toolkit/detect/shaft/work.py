"""Where the shaft detector looks: the valid part of the image and a reduced, undistorted
colour copy of it (the *work frame*).

Three pixel frames: *raw* (the input image), *ideal* (undistorted pixels ``K (x, y, 1)``
of the camera, the raw ones themselves without a camera) and *work*: a reduced copy of the
ideal frame, an affine map of it (``ideal = (work + 0.5) / scale + origin``), so that
straight edges stay straight there and a region's boundaries can be fitted by lines.
Pixel (0, 0) is the centre of the top-left pixel in every frame.

The reduction is area averaging (INTER_AREA), its pass over the full image shared by the
work frames of one image (`Reductions`: the same values, about 1.9 ms of CPU a 1080p frame for
the detector's 480 px and the pixel evidence's 320 px frames where two resizes took 3.9).

`Validity` answers where samples may be taken: inside the image and inside the caller's
valid region (an object with ``distance_to_boundary(points)``, e.g. `region.ValidRegion`),
as a signed distance [raw px] interpolated from a coarse grid of the region's own distance
(exact for a straight boundary, within 0.1 px for a field stop's circle). Without a region
only the image border bounds it. `WorkFrame` is the reduced copy with its valid mask and the
distance to the boundary in work pixels.

Without a camera the axis of a shaft is still the image of a plane through the camera
centre (`shaft.axis`); `axis_matrix` then gives a nominal pinhole (focal length the image
width, principal point the image centre), `nominal` says so.

Example
-------
>>> import numpy as np
>>> img = np.zeros((300, 400, 3), np.uint8)
>>> wf = WorkFrame(img, None, Validity(None, (300, 400)), target_px=200)
>>> wf.shape, wf.mean_scale, np.round(wf.to_ideal([[0.0, 0.0]]), 2).tolist()
((150, 200), 0.5, [[0.5, 0.5]])
>>> round(float(Validity(None, (300, 400)).distance(np.array([[10.0, 150.0]]))[0]), 1)
10.0
"""
from __future__ import annotations

import numpy as np

__all__ = ["Validity", "WorkFrame", "Reductions", "axis_matrix", "grid_map", "raw_masks", "RAW_STEP_PX",
           "CLIPPED_LEVEL", "MAX_CLIPPED"]

_GRID_PX = 16.0  # spacing of the coarse grid the region's distance is interpolated from [raw px]
_MAP_STEP = 8.0  # the lens map is evaluated every this many work px and interpolated [px]
_STRIPE_ROWS = 64  # rows of the full image `Reductions` converts at a time (even)
_MAX_STRETCH = 0.8  # the work frame covers at most this fraction of the raw size either side of the centre


def axis_matrix(camera, shape):
    """K (3, 3) for the back-projection of edges: the camera's, or without a camera a
    nominal pinhole (f = image width [px], principal point at the image centre); and
    whether it is nominal.

    >>> K, nominal = axis_matrix(None, (480, 640)); float(K[0, 0]), K[:2, 2].tolist(), nominal
    (640.0, [319.5, 239.5], True)
    """
    if camera is not None:
        return np.asarray(camera.K, float), False
    H, W = shape
    return np.array([[float(W), 0.0, (W - 1) / 2.0], [0.0, float(W), (H - 1) / 2.0], [0.0, 0.0, 1.0]]), True


class Validity:
    """Where the shaft detector may sample: the image and the caller's valid region.

    Parameters
    ----------
    region : object or None
        Has ``distance_to_boundary(points (..., 2) [px]) -> (...)`` signed [px], positive
        inside, and ``covers_image(shape)`` (`region.ValidRegion`); None: the whole image.
    shape : (H, W)
        The image size [px].

    The region's distance is evaluated on a grid `_GRID_PX` apart and interpolated
    bilinearly; the image border always bounds it (distance to the nearest border pixel
    centre).
    """

    def __init__(self, region, shape):
        self.shape = (int(shape[0]), int(shape[1]))
        H, W = self.shape
        self.region = None if region is None or region.covers_image(self.shape) else region
        self._grid = None
        if self.region is not None and hasattr(region, "distance_grid"):
            # a region's grid is made once (`ValidRegion.distance_grid`): the frames of a video
            # share one region, and the grid costs ~2 ms a 1080p frame
            self._grid = region.distance_grid(self.shape, _GRID_PX)
        elif self.region is not None:
            gx = np.arange(0.0, W - 1 + _GRID_PX, _GRID_PX)
            gy = np.arange(0.0, H - 1 + _GRID_PX, _GRID_PX)
            X, Y = np.meshgrid(gx, gy)
            d = np.asarray(region.distance_to_boundary(np.stack([X, Y], -1)), np.float32)
            self._grid = np.ascontiguousarray(d)

    def distance(self, pts):
        """Signed distance (...) [raw px] of raw points (..., 2) to the nearest of the image
        border and the region's boundary, positive inside."""
        import cv2

        p = np.asarray(pts, float)
        H, W = self.shape
        x, y = p[..., 0], p[..., 1]
        with np.errstate(invalid="ignore"):
            d = np.minimum(np.minimum(x, W - 1.0 - x), np.minimum(y, H - 1.0 - y))
        d = np.where(np.isfinite(d), d, -np.inf)
        if self._grid is None:
            return d
        flat = p.reshape(-1, 2)
        n = flat.shape[0]
        if n == 0:
            return d
        cols = min(n, 2048)
        rows = -(-n // cols)
        mx = np.full(rows * cols, -1.0, np.float32)
        my = np.full(rows * cols, -1.0, np.float32)
        mx[:n] = np.nan_to_num(flat[:, 0] / _GRID_PX, nan=-1e4)
        my[:n] = np.nan_to_num(flat[:, 1] / _GRID_PX, nan=-1e4)
        g = cv2.remap(self._grid, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE).reshape(-1)[:n]
        return np.minimum(d, g.reshape(d.shape))

    def grid_distance(self, xs, ys):
        """`distance` (len(ys), len(xs)) of the grid of raw points (xs[j], ys[i]): the same
        values; without a region the image border's part taken separably (what a work frame
        without a lens needs: its pixels' raw points are such a grid)."""
        xs, ys = np.asarray(xs, float), np.asarray(ys, float)
        if self._grid is not None:
            return self.distance(np.stack(np.broadcast_arrays(xs[None, :], ys[:, None]), -1))
        H, W = self.shape
        with np.errstate(invalid="ignore"):
            d = np.minimum(np.minimum(xs, W - 1.0 - xs)[None, :], np.minimum(ys, H - 1.0 - ys)[:, None])
        return np.where(np.isfinite(d), d, -np.inf)

    def border_distances(self, xs, ys):
        """(dx (len(xs),), dy (len(ys),)): `grid_distance` = min(dx[None, :], dy[:, None])
        where it is the image border's distance alone (no region) and every point is
        finite; else None."""
        xs, ys = np.asarray(xs, float), np.asarray(ys, float)
        if self._grid is not None or not (np.all(np.isfinite(xs)) and np.all(np.isfinite(ys))):
            return None
        H, W = self.shape
        return np.minimum(xs, W - 1.0 - xs), np.minimum(ys, H - 1.0 - ys)

    def ok(self, pts, margin_px=0.0):
        """(...) bool: raw points (..., 2) at least margin_px [px] inside."""
        return self.distance(pts) >= margin_px


class Reductions:
    """An image and its area-averaged reductions (OpenCV's INTER_AREA, bit for bit), sharing
    one pass over the full image between the work frames of the image (`WorkFrame`'s
    ``reductions``: the shaft detector's at 480 px, the pixel evidence's at 320).

    An 8-bit image reduced by an even factor f = 2 m >= 4 along both axes (1080p to 480 or 320
    px: 4 and 6) is reduced through the exact sums of its 2 x 2 blocks times 4, made once
    (uint16, by OpenCV's fast halving of the image times 16: (16 a + 16 b + 16 c + 16 d + 2) >> 2
    = 4 (a + b + c + d)), then the sums of m x m of those (for m = 2 their halving: (4 p + 4 q +
    4 r + 4 s + 2) >> 2 = p + q + r + s, the block's sum itself; for m = 3 or 4 whole rows of
    them added, `_block_sums`: integers below 2^16, exact; larger m from the sums themselves),
    scaled and rounded as INTER_AREA rounds (float32 product, the nearest level, ties to even:
    one `cv2.convertScaleAbs`; a sum times 4 over 4 f^2 is the same float32 product, powers of
    two being exact): the same values as `cv2.resize` (tests/toolkit/detect/shaft/test_work.py),
    at about half the CPU of the two reductions at once. Any other image or factor:
    `cv2.resize` itself.

    >>> import numpy as np, cv2
    >>> img = np.random.default_rng(0).integers(0, 256, (24, 36, 3), dtype=np.uint8)
    >>> r = Reductions(img)
    >>> all(np.array_equal(r.to(w, h), cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA))
    ...     for w, h in ((9, 6), (6, 4), (12, 8), (18, 12), (10, 7)))
    True
    """

    def __init__(self, image):
        self.image = image
        self._pairs = None

    def to(self, w, h):
        """The image reduced to w x h [px] (class docstring)."""
        import cv2

        img = self.image
        H, W = img.shape[:2]
        f = W // w
        if (w, h) == (W, H):
            return img
        if not (img.dtype == np.uint8 and f % 2 == 0 and 4 <= f <= 16 and W == f * w and H == f * h):
            return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        if self._pairs is None:
            # by stripes of rows: the uint16 copy stays in the cache, and no frame-sized
            # buffer is allocated (its page faults cost more than the conversion)
            self._pairs = np.empty((H // 2, W // 2) + img.shape[2:], np.uint16)  # the 2 x 2 sums times 4
            u = np.empty((min(H, _STRIPE_ROWS), W) + img.shape[2:], np.uint16)
            for r in range(0, H, _STRIPE_ROWS):
                n = min(_STRIPE_ROWS, H - r)
                np.left_shift(img[r:r + n], 4, out=u[:n], dtype=np.uint16)
                cv2.resize(u[:n], (W // 2, n // 2), dst=self._pairs[r // 2:(r + n) // 2], interpolation=cv2.INTER_AREA)
        m = f // 2
        times = 4  # the sums below are the blocks' sums times this
        if m == 2 or (img.ndim == 3 and img.shape[2] > 4):
            # OpenCV's fast halving (SIMD) of the pairs' sums times 4: the blocks' sums (no
            # multiplication of the pairs by 4 first)
            p = self._pairs if m == 2 else (self._pairs >> 2) * np.uint16(m * m)
            sums, times = cv2.resize(p, (w, h), interpolation=cv2.INTER_AREA), 1
        else:
            # the m x m sums by whole-row additions: INTER_AREA's generic path of the sums times
            # m^2 costs three times more (0.73 against 0.26 ms for a 1080p frame's 320 px copy);
            # the sums times 4 stay below 2^16 up to m = 4
            sums = _block_sums(self._pairs if m <= 4 else self._pairs >> 2, m)
            times = 4 if m <= 4 else 1
        # rint(sum x float32(1 / f^2)) in float32, as one pass (the scale a power of two apart
        # for the sums times 4: the same product)
        return cv2.convertScaleAbs(sums, alpha=float(np.float32(1.0 / (times * f * f))))


def _block_sums(a, m):
    """The sums (h // m, w // m, ...) of the m x m blocks of a (h, w, ...) uint16 (h, w multiples of
    m; every sum below 2^16): the m rows of each block added as whole rows of pixels (strided views,
    one `cv2.add` each), then, transposed, the m columns likewise: integers, exact.

    >>> a = np.arange(6 * 9, dtype=np.uint16).reshape(6, 9)
    >>> _block_sums(a, 3).tolist() == a.reshape(2, 3, 3, 3).sum((1, 3)).tolist()
    True
    """
    import cv2

    h, w = a.shape[:2]
    rest = a.shape[2:]

    def rows(x, n, k):  # x (n * m, k) -> the sums of each m consecutive rows (n, k)
        v = x.reshape(n, m, k)
        out = cv2.add(v[:, 0], v[:, 1])
        for q in range(2, m):
            out = cv2.add(out, v[:, q], dst=out)
        return out

    r = rows(a.reshape(h, -1), h // m, a[0].size).reshape((h // m, w) + rest)
    t = cv2.transpose(r)  # (w, h // m, ...)
    c = rows(t.reshape(w, -1), w // m, t[0].size).reshape((w // m, h // m) + rest)
    return cv2.transpose(c)


def _ideal_box(camera, W, H):
    """The ideal-frame box (x0, y0, x1, y1) [px] the work frame covers: the raw image's
    border undistorted, at most `_MAX_STRETCH` of the raw size either side of the principal
    point (a strong barrel model blows up at the corners)."""
    if camera is None:
        return -0.5, -0.5, W - 0.5, H - 0.5
    t = np.linspace(0.0, 1.0, 64)
    b = np.concatenate([np.c_[t * (W - 1), 0 * t], np.c_[t * (W - 1), 0 * t + H - 1],
                        np.c_[0 * t, t * (H - 1)], np.c_[0 * t + W - 1, t * (H - 1)]])
    u = camera.undistort_pixels(b)
    u = u[np.all(np.isfinite(u), -1)]
    cx, cy = float(camera.K[0, 2]), float(camera.K[1, 2])
    x0, y0 = u.min(0) - 0.5
    x1, y1 = u.max(0) + 0.5
    return (max(x0, cx - _MAX_STRETCH * W), max(y0, cy - _MAX_STRETCH * H),
            min(x1, cx + _MAX_STRETCH * W), min(y1, cy + _MAX_STRETCH * H))


class WorkFrame:
    """The reduced, undistorted copy of an image the shaft proposals are found in.

    Parameters
    ----------
    image : (H, W, 3) or (H, W) array
        BGR or grey, uint8 (other dtypes are used as float32).
    camera : Camera or None
        Lens model (None: raw = ideal pixels).
    validity : Validity
        Where the raw image may be sampled.
    target_px : float
        The work frame's longer side [px] (never enlarged).
    reductions : Reductions, optional
        The image's reductions, shared with its other work frames (default: its own);
        ``image`` is then that one's image.

    Attributes
    ----------
    scale : (2,)
        Work px per ideal px along x and y.
    origin : (2,) [ideal px]
        Where the work frame's corner (-0.5, -0.5) lies: ``ideal = (work + 0.5) / scale +
        origin``.
    shape : (h, w)
    bgr : (h, w, 3) or (h, w)
        The reduced copy (area-averaged, then remapped through the lens model).
    luma : (h, w) float32 [grey levels]
    valid : (h, w) bool
        Work pixels inside the image and the valid region.
    dist : (h, w) float32 [work px]
        Their distance to the boundary (raw distance x scale: a lower bound where the lens
        stretches the periphery).
    reductions : Reductions
        The image's reductions (the ones given, or its own).
    """

    def __init__(self, image, camera, validity, target_px=480.0, reductions=None):
        import cv2

        if reductions is None:
            img = np.asarray(image)
            reductions = Reductions(img if img.dtype == np.uint8 else img.astype(np.float32))
        self.reductions = reductions
        img = reductions.image
        H, W = img.shape[:2]
        x0, y0, x1, y1 = _ideal_box(camera, W, H)
        s = min(1.0, float(target_px) / max(x1 - x0, y1 - y0))
        w, h = max(int(round((x1 - x0) * s)), 8), max(int(round((y1 - y0) * s)), 8)
        self.shape = (h, w)
        self.scale = np.array([w / (x1 - x0), h / (y1 - y0)])
        self.origin = np.array([x0, y0], float)
        if camera is None:  # the work pixels' raw points are a grid
            self.bgr = reductions.to(w, h)
            xs = self.to_ideal(np.stack([np.arange(w), np.zeros(w)], -1))[:, 0]
            ys = self.to_ideal(np.stack([np.zeros(h), np.arange(h)], -1))[:, 1]
            sep = validity.border_distances(xs, ys)
            d = validity.grid_distance(xs, ys) if sep is None else None
        else:
            raw = self._raw_of_grid(camera, h, w)
            sr = min(1.0, 1.25 * s)  # reduce first (no aliasing), then remap
            rw, rh = max(int(round(W * sr)), 8), max(int(round(H * sr)), 8)
            small = reductions.to(rw, rh) if sr < 1 else img
            mx = np.nan_to_num((raw[..., 0] + 0.5) * (rw / W) - 0.5, nan=-1e4).astype(np.float32)
            my = np.nan_to_num((raw[..., 1] + 0.5) * (rh / H) - 0.5, nan=-1e4).astype(np.float32)
            self.bgr = cv2.remap(small, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            d = validity.distance(raw)
        if self.bgr.ndim == 3:
            self.luma = cv2.cvtColor(self.bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
        else:
            self.luma = self.bgr.astype(np.float32)
        sc = float(np.mean(self.scale))
        if d is None:
            # the border's distance, separable: min(dx, dy) x sc in float32 is min(dx x sc,
            # dy x sc) in float32 (both roundings are monotonic), one pass over the frame
            # instead of six, the same values
            self.dist = np.minimum((sep[0] * sc).astype(np.float32)[None, :], (sep[1] * sc).astype(np.float32)[:, None])
        else:
            d = d * sc
            self.dist = np.where(np.isfinite(d), d, -1.0).astype(np.float32)
        self.valid = self.dist >= 0

    @property
    def colours(self):
        """The copy as float32 (h, w, C) (C = 1 for a grey one), made once: the stages that
        sample it share it (read-only)."""
        if getattr(self, "_colours", None) is None:
            self._colours = self.bgr.astype(np.float32).reshape(self.shape + (-1,))
            self._colours.flags.writeable = False
        return self._colours

    @property
    def mean_scale(self):
        """Work px per ideal px (the mean of the two axes' scales, which differ by < 1 %)."""
        return float(np.mean(self.scale))

    def _raw_of_grid(self, camera, h, w):
        """Raw pixels (h, w, 2) of every work pixel: the lens map evaluated every
        `_MAP_STEP` work px and interpolated bilinearly in between (`grid_map`: it bends by
        far less than a work pixel over that span); NaN where a node is beyond the lens
        model's reach."""
        return grid_map(lambda p: camera.distort_pixels(self.to_ideal(p)), (h, w), _MAP_STEP)

    def to_ideal(self, p):
        """Ideal pixels (..., 2) of work pixels p (..., 2)."""
        return (np.asarray(p, float) + 0.5) / self.scale + self.origin

    def to_work(self, q):
        """Work pixels (..., 2) of ideal pixels q (..., 2)."""
        return (np.asarray(q, float) - self.origin) * self.scale - 0.5


def grid_map(f, shape, step):
    """A smooth map's values (h, w, C) at every pixel of a frame of `shape` (h, w), from its
    values on a coarse grid: f maps pixels (..., 2) [x, y] to values (..., C) and is evaluated
    at the nodes (step * i, step * j) only, the last node of a row or column at or past the
    last pixel; pixel (x, y) takes the bilinear interpolation at grid position (x / step,
    y / step), so that a node's pixel takes the node's value exactly (a resize of the node
    grid would read pixel x at (x + 0.5) / step - 0.5: the map half a step less one half pixel
    off). NaN where a non-finite node has weight.

    The grid is the speed: a map that bends by far less than a pixel over a step (a lens's,
    an affine one) costs its evaluation at 1 / step**2 of the pixels.

    >>> m = grid_map(lambda p: 2.0 * p + 1.0, (5, 7), 4.0)     # affine: exact at every pixel
    >>> m.shape, m[3, 6].tolist(), m[4, 5].tolist()
    ((5, 7, 2), [13.0, 7.0], [11.0, 9.0])
    >>> m = grid_map(lambda p: np.where(p[..., :1] > 6, np.nan, p), (2, 12), 4.0)   # nodes x = 8, 12 lost
    >>> np.isnan(m[0, :, 0]).nonzero()[0].tolist()                   # every pixel they weigh on
    [5, 6, 7, 8, 9, 10, 11]
    """
    h, w = shape
    return _grid_pixels(*_grid_nodes(f, shape, step), step, (0, 0, w, h))


def _grid_nodes(f, shape, step):
    """The nodes of `grid_map`: (values (gh, gw, C) float32, 0 where not finite; not finite
    (gh, gw) bool)."""
    h, w = shape
    gx = np.arange(0.0, w - 1 + step, step)
    gy = np.arange(0.0, h - 1 + step, step)
    nodes = np.asarray(f(np.stack(np.meshgrid(gx, gy), -1)), float)
    bad = ~np.all(np.isfinite(nodes), -1)
    return np.where(bad[..., None], 0.0, nodes).astype(np.float32), bad


def _grid_pixels(nodes, bad, step, box):
    """`grid_map`'s values (y1 - y0, x1 - x0, C) at the pixels of box (x0, y0, x1, y1) (end
    exclusive): each pixel's own interpolation, the same as in the whole frame's."""
    import cv2

    x0, y0, x1, y1 = box
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    mx, my = xx / np.float32(step), yy / np.float32(step)

    def at_pixels(grid):
        return cv2.remap(np.ascontiguousarray(grid), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    out = np.stack([at_pixels(nodes[..., k]) for k in range(nodes.shape[-1])], -1).astype(np.float64)
    if np.any(bad):
        out[at_pixels(bad.astype(np.float32)) > 0] = np.nan
    return out


#: A work pixel is clipped where a channel reaches this 8-bit level (2 % below the ceiling: the
#: work frame's area averaging leaves a clipped patch's inside at 255, its rim a little lower).
CLIPPED_LEVEL = 250
#: A region (`shaft.parts`, `shaft.border_band`) is glare when more than this fraction of its pixels are clipped (most of it): not
#: tuned.
MAX_CLIPPED = 0.5
#: The raw-to-work map of `raw_masks` is evaluated every this many raw px and interpolated.
RAW_STEP_PX = 4.0


def raw_masks(work, camera, lab, count, shape):
    """The regions' labels (h, w) [work px] carried to the raw frame of `shape` (H, W): one
    (H, W) bool mask per region, each raw pixel the label of the work pixel nearest to its
    own work point (the raw-to-work map evaluated on a `RAW_STEP_PX` raw grid, `grid_map`); 0
    beyond the work frame and the lens model's reach."""
    import cv2

    from pencilcal.toolkit.detect.working import to_working_points

    H, W = shape
    masks = [np.zeros((H, W), bool) for _ in range(count)]
    rows, cols = np.nonzero(lab > 0)
    if rows.size == 0:
        return masks
    step = RAW_STEP_PX
    nodes, bad = _grid_nodes(lambda g: work.to_work(to_working_points(camera, g)), shape, step)
    # only the raw pixels whose work point may fall on a label: a pixel's point lies in the box
    # of its cell's finite nodes (a convex combination of them), so the cells whose box meets
    # the labels' (one pixel wider: the nearest pixel) hold every such pixel
    v = np.where(bad[..., None], np.nan, nodes.astype(np.float64))
    corners = np.stack([v[:-1, :-1], v[:-1, 1:], v[1:, :-1], v[1:, 1:]])
    lo, hi = np.fmin.reduce(corners, 0), np.fmax.reduce(corners, 0)  # (gh - 1, gw - 1, 2); NaN: all lost
    near = ((hi[..., 0] >= cols.min() - 1.0) & (lo[..., 0] <= cols.max() + 1.0)
            & (hi[..., 1] >= rows.min() - 1.0) & (lo[..., 1] <= rows.max() + 1.0))
    if not near.any():
        return masks
    ci, cj = np.nonzero(near)
    x0, y0 = int(cj.min() * step), int(ci.min() * step)
    x1, y1 = min(int((cj.max() + 1) * step) + 1, W), min(int((ci.max() + 1) * step) + 1, H)
    q = np.nan_to_num(_grid_pixels(nodes, bad, step, (x0, y0, x1, y1)), nan=-1.0).astype(np.float32)
    raw = cv2.remap(lab.astype(np.float32), q[..., 0], q[..., 1], cv2.INTER_NEAREST,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    for k, m in enumerate(masks, 1):
        m[y0:y1, x0:x1] = raw == k
    return masks
