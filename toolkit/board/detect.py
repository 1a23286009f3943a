"""Board detection: ChArUco with cv2.aruco.CharucoDetector, chessboards with findChessboardCornersSB.

`detect_board` returns the corners it found with their ids (ChArUco corner ids, or the
row-major index of a chessboard's inner corner), in raw pixels (OpenCV convention: pixel
(0, 0) is the centre of the top-left pixel), refined to subpixel precision:

- ChArUco: markers are detected, completed against the board layout (refineDetectedMarkers
  recovers markers the first pass missed), and the chessboard corners between them are
  interpolated and refined by cornerSubPix inside CharucoDetector, and kept so by default.
  With ``symmetric=True`` each corner is then refined to its point of symmetry
  (`refine_charuco_corners`, `symmetric_corners` below) in a half-window of a fifth of the
  corner spacing, 2-10 px (the markers, centred in their squares, are point symmetric about
  the corner too; their inner bits fall where the weights are small). It is opt-in: the
  refined corners leave an error shared by the views that the corner-noise model counts as
  each view's own (a stereo rig's PnP sigmas about 1.5 x too large, its coverage 83 % for
  68 +- 8 %), and a view's detection costs 2.5-3 x CharucoDetector's (docs/calibration.md).
  On rendered views of the da Vinci and RealSense boards (blur 0.7-2.5 px, vignetting,
  noise, JPEG) CharucoDetector's corners err by 0.06-0.56 px RMS per axis, the refined ones
  by 0.015-0.04 px, each view's mean error along the radius within 0.01 px; on the real da
  Vinci views the calibration's RMS falls from 0.56 to 0.23-0.25 px. A cornerSubPix window
  fitted to the squares or to the white gap did worse than CharucoDetector's own wherever
  the blur reached 1.5 px (the markers' edges enter it);
- chessboard: the sector-based detector (findChessboardCornersSB), with the classic
  findChessboardCorners where it finds nothing; it finds the whole board or nothing. Its
  corners are then refined by cornerSubPix with a window fitted to each corner's squares
  (`refine_chessboard_corners`): on rendered 960x540 views (11 x 8 inner corners, barrel
  distortion, blur 0.7-2.5 px, noise 2-6 grey levels, JPEG 85) the sector detector's
  corners err by 0.30-0.57 px RMS per axis, and smoothly across a view (an error the pose
  cannot absorb); refined, by 0.02-0.09 px. Then, in the same window, to the point about
  which the corner is symmetric under a light whose gain and offset vary linearly across
  the window (`symmetric_corners`): cornerSubPix's balance of gradients follows a
  vignetting's falloff towards the brighter side (on rendered endoscope views falling to a
  third at the image's corners, blur 1.8 px: each view's mean radial error -0.02 to -0.04
  px, 0.04-0.07 px RMS), the point of symmetry does not (-0.003 to +0.002 px, 0.009-0.028
  px RMS).

Example
-------
>>> import numpy as np, cv2
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> board = board_from_dict({"type": "chessboard", "squares": [6, 4], "square": 30.0})
>>> img = np.full((400, 560), 255, np.uint8)
>>> for j in range(5):
...     for i in range(7):
...         if (i + j) % 2 == 0:
...             img[50 + j * 60:110 + j * 60, 70 + i * 60:130 + i * 60] = 0
>>> det = detect_board(img, board)
>>> det.ids.size, np.round(det.corners[0], 1).tolist()
(24, [129.5, 109.5])
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BoardDetection", "detect_board", "refine_charuco_corners", "refine_chessboard_corners",
           "symmetric_corners"]

# cornerSubPix's half-window per corner: this share of the distance to its nearest grid
# neighbour (the window then holds one X-junction), within these bounds [px]; a corner it
# moves by more than MAX_MOVE of that distance keeps the detector's position
_WINDOW_SHARE = 0.35
_WINDOW_MIN, _WINDOW_MAX = 2, 10
_MAX_MOVE = 0.25
# the symmetric refinement's Gauss-Newton: at most this many steps, settled below this step [px]
_SYM_ITERATIONS, _SYM_TOL = 12, 1e-3
# ChArUco corners: the symmetric refinement's half-window, this share of the corner spacing
# (set before the real sets were measured with it, not varied on them)
_CHARUCO_SHARE = 0.2


@dataclass(frozen=True)
class BoardDetection:
    """Corners found on one image.

    ids: (K,) int corner ids (Board.object_points() rows); corners: (K, 2) raw pixels;
    image_size: (width, height); marker_ids: (L,) ArUco ids seen (charuco; empty otherwise);
    marker_corners: (L, 4, 2) their corners in raw pixels; symmetric: the corners were
    refined to their point of symmetry (`detect_board`: a chessboard's always, a ChArUco
    board's when asked).
    """

    ids: np.ndarray
    corners: np.ndarray
    image_size: tuple
    marker_ids: np.ndarray
    marker_corners: np.ndarray
    symmetric: bool = False

    @property
    def count(self) -> int:
        return int(self.ids.size)


def _gray(image):
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        # 16-bit or float images: scale to 8 bits for the detectors
        lo, hi = float(np.min(img)), float(np.max(img))
        img = np.clip((img - lo) * (255.0 / max(hi - lo, 1e-12)), 0, 255).astype(np.uint8)
    return img


_DETECTORS = {}


def _charuco_detectors(board):
    """(ArucoDetector, CharucoDetector, cv2 board, frozenset of its marker ids) for a charuco
    board, cached."""
    import cv2

    key = (board.squares, board.square, board.marker, board.dictionary, board.legacy)
    dets = _DETECTORS.get(key)
    if dets is None:
        # No subpixel refinement of the *marker* corners (DetectorParameters' default): the
        # ChArUco corners are refined by cornerSubPix anyway, and on blurry endoscope video
        # (da Vinci set) refined marker corners made the final corners noisier
        # (calibration RMS 0.531 -> 0.576 px).
        params = cv2.aruco.DetectorParameters()
        cboard = board.cv2_board()
        # the markers are found by the ArucoDetector CharucoDetector would build (same
        # dictionary, detector and default refine parameters) and handed to it
        aruco = cv2.aruco.ArucoDetector(cboard.getDictionary(), params, cv2.aruco.RefineParameters())
        charuco = cv2.aruco.CharucoDetector(cboard, cv2.aruco.CharucoParameters(), params)
        dets = (aruco, charuco, cboard, frozenset(np.asarray(cboard.getIds(), int).ravel().tolist()))
        _DETECTORS[key] = dets
    return dets


def _detect_charuco(gray, board):
    """CharucoDetector.detectBoard with tryRefineMarkers, the refinement run only when a
    board marker is missing.

    Re-finding the markers the first pass missed from the board layout
    (refineDetectedMarkers, what tryRefineMarkers does inside detectBoard) gives +37 %
    corners on the blurry da Vinci set (49 usable views instead of 47, RMS 0.562 px). With
    every marker of the board found there is nothing to re-find and the result is the
    same without it (~0.2 ms of a 15 ms detection at 1280x720).
    Returns (charuco corners, charuco ids, marker corners, marker ids) as detectBoard does.
    """
    aruco, charuco, cboard, board_ids = _charuco_detectors(board)
    mc, mi, rejected = aruco.detectMarkers(gray)
    if mi is None or len(mi) == 0:
        return None, None, (), None
    if not board_ids.issubset(np.asarray(mi).ravel().tolist()):
        mc, mi, rejected, _ = aruco.refineDetectedMarkers(gray, cboard, mc, mi, rejected)
    return charuco.detectBoard(gray, markerCorners=mc, markerIds=mi)


def refine_chessboard_corners(gray, corners, cols, rows):
    """Chessboard corners (cols * rows, 2) [px], row-major, refined by cornerSubPix with a
    half-window of `_WINDOW_SHARE` of each corner's distance to its nearest grid neighbour
    (2-10 px); a corner moved by more than a quarter of that distance keeps its place.

    >>> import numpy as np
    >>> img = np.full((120, 160), 220, np.uint8)
    >>> for j in range(4):
    ...     for i in range(5):
    ...         if (i + j) % 2:
    ...             img[10 + 25 * j:35 + 25 * j, 15 + 25 * i:40 + 25 * i] = 30
    >>> guess = np.array([[40.3 + 25 * i, 35.4 + 25 * j] for j in range(2) for i in range(3)])
    >>> np.round(refine_chessboard_corners(img, guess, 3, 2)[0], 1).tolist()
    [39.5, 34.5]
    """
    import cv2

    c = np.asarray(corners, float).reshape(rows, cols, 2)
    d = np.full((rows, cols), np.inf)
    dx = np.linalg.norm(np.diff(c, axis=1), axis=-1)
    dy = np.linalg.norm(np.diff(c, axis=0), axis=-1)
    d[:, :-1], d[:, 1:] = np.minimum(d[:, :-1], dx), np.minimum(d[:, 1:], dx)
    d[:-1, :], d[1:, :] = np.minimum(d[:-1, :], dy), np.minimum(d[1:, :], dy)
    d = d.ravel()
    w = np.clip(np.floor(_WINDOW_SHARE * d), _WINDOW_MIN, _WINDOW_MAX).astype(int)
    out = c.reshape(-1, 2).copy()
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.001)
    prepared = _with_gradient(gray)
    for win in np.unique(w):
        sel = np.flatnonzero(w == win)
        r = cv2.cornerSubPix(gray, out[sel].astype(np.float32).reshape(-1, 1, 2), (int(win), int(win)), (-1, -1),
                             criteria).reshape(-1, 2).astype(float)
        ok = np.all(np.isfinite(r), 1) & (np.linalg.norm(r - out[sel], axis=1) <= _MAX_MOVE * d[sel])
        # then the point about which the window is symmetric, under a brightness that varies
        # linearly across it (what cornerSubPix's gradient balance follows, `symmetric_corners`)
        s, s_ok = symmetric_corners(gray, r, int(win), prepared=prepared)
        s_ok &= np.linalg.norm(s - out[sel], axis=1) <= _MAX_MOVE * d[sel]
        r[s_ok] = s[s_ok]
        out[sel[ok]] = r[ok]
    return out


def refine_charuco_corners(gray, corners, ids, cols, share=_CHARUCO_SHARE):
    """ChArUco corners (K, 2) [px] with their ids (K,) (row-major over `cols` inner corners
    per row) refined to their point of symmetry (`symmetric_corners`) in a half-window of
    `share` of each corner's distance to its nearest detected grid neighbour (the view's
    median spacing where it has none; 2-10 px, the chessboards' bounds: on the RealSense
    views, windows up to 20 px gave an RMS of 0.577 px against 0.585 for 1.5 x the
    refinement's CPU); a corner the refinement fails on, or moves by more than a quarter of
    that distance, keeps its place.
    Returns (refined (K, 2), refined? (K,)).

    Two corners 25 px apart (a half-window of 5 px), found 0.3-0.5 px off:

    >>> import numpy as np, cv2
    >>> img = np.full((120, 160), 220, np.uint8)
    >>> for j in range(4):
    ...     for i in range(5):
    ...         if (i + j) % 2:
    ...             img[10 + 25 * j:35 + 25 * j, 15 + 25 * i:40 + 25 * i] = 30
    >>> img = cv2.GaussianBlur(img, (0, 0), 1.2)
    >>> q, done = refine_charuco_corners(img, [[39.9, 34.2], [64.8, 34.9]], [0, 1], 3)
    >>> np.round(q, 2).tolist(), done.tolist()
    ([[39.5, 34.5], [64.5, 34.5]], [True, True])
    """
    c = np.asarray(corners, float).reshape(-1, 2)
    ids = np.asarray(ids, int).ravel()
    out, done = c.copy(), np.zeros(len(c), bool)
    if len(c) < 2:
        return out, done
    g = np.stack([ids % cols, ids // cols], -1)
    grid = np.abs(g[:, None, :] - g[None, :, :]).sum(-1)
    px = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=-1)
    d = np.where(grid == 1, px, np.inf).min(1)
    if not np.any(np.isfinite(d)):
        return out, done
    d = np.where(np.isfinite(d), d, np.median(d[np.isfinite(d)]))
    w = np.clip(np.round(share * d), _WINDOW_MIN, _WINDOW_MAX).astype(int)
    # the image about the corners only (a board may fill a small part of a large frame): the
    # windows and the moves a corner may make stay inside, as the image's own border does
    img = np.asarray(gray)
    pad = int(np.max(w) + np.ceil(_MAX_MOVE * np.max(d))) + 3
    x0, y0 = np.maximum(np.floor(c.min(0)).astype(int) - pad, 0)
    x1, y1 = np.minimum(np.ceil(c.max(0)).astype(int) + pad + 1, [img.shape[1], img.shape[0]])
    crop = img[y0:y1, x0:x1]
    prepared = _with_gradient(crop)
    for win in np.unique(w):
        sel = np.flatnonzero(w == win)
        s, ok = symmetric_corners(crop, c[sel] - [x0, y0], int(win), prepared=prepared)
        s = s + [x0, y0]
        ok &= np.linalg.norm(s - c[sel], axis=1) <= _MAX_MOVE * d[sel]
        out[sel[ok]], done[sel[ok]] = s[ok], True
    return out, done


def _bilinear(img, x, y):
    """img (H, W) or (H, W, C) sampled at (x, y) (...) [px], bilinearly: (...) or (..., C);
    x, y within the image."""
    h, w = img.shape[:2]
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx, fy = x - x0, y - y0
    if img.ndim == 3:
        fx, fy = fx[..., None], fy[..., None]
    top = img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx
    bottom = img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def _with_gradient(gray):
    """The image, its d/dx and its d/dy, (H, W, 3) float64: what `symmetric_corners` samples,
    all three at each point at once; computed once per image by the callers that refine at
    several window sizes."""
    img = np.asarray(gray, np.float64)
    gy, gx = np.gradient(img)
    return np.stack([img, gx, gy], -1)


def symmetric_corners(gray, corners, half_window, iterations=_SYM_ITERATIONS, prepared=None):
    """X-junctions (N, 2) [px] refined to the point q about which each window is point
    symmetric, under an illumination whose gain and offset vary linearly across the window.

    A chessboard corner seen through any blur with a symmetric spot is point symmetric,
    I(q + d) = I(q - d), whatever the angle between its edges. An illumination
    g(d) * I + o(d) with gain g and offset o linear in d breaks that, but exactly so:
    I(q + d) - I(q - d) = (a . d) (I(q + d) + I(q - d)) + b . d with two 2-vectors a, b.
    So q, a and b are fitted by Gauss-Newton over half of the (2 h + 1)^2 window's offsets d,
    weighted by exp(-|d|^2 / h^2), from the given corners (cornerSubPix's, whose balance of
    gradients a vignetting's falloff shifts towards the brighter side: on a rendered corner
    at 1.5 px of blur, +0.05 px at a falloff of 0.4 % per px; this refinement, 0.001 px).

    gray: (H, W) image; corners: (N, 2) starts [px]; half_window: h [px]; prepared: the
    image with its gradient (`_with_gradient(gray)`) where the caller has it already.
    Returns (refined (N, 2), ok (N,)): ok is False where the window leaves the image, the
    normal equations are singular or the fit did not settle (those rows keep their start).

    A corner at (19.5, 20.5), blurred, its light falling 1 % per px to the right:

    >>> import numpy as np, cv2
    >>> yy, xx = np.mgrid[0:40, 0:40] + 0.0
    >>> img = cv2.GaussianBlur(np.where((xx < 20) == (yy < 21), 200.0, 40.0), (0, 0), 1.5) * (1 - 0.01 * (xx - 20))
    >>> start = np.array([[19.0, 20.0]], np.float32)
    >>> crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.001)
    >>> np.round(cv2.cornerSubPix(img.astype(np.float32), start, (6, 6), (-1, -1), crit)[0].astype(float), 2).tolist()
    [19.39, 20.33]
    >>> q, ok = symmetric_corners(img, start, 6)
    >>> np.round(q[0], 2).tolist(), bool(ok[0])
    ([19.5, 20.5], True)
    """
    stack = prepared if prepared is not None else _with_gradient(gray)
    q0 = np.asarray(corners, float).reshape(-1, 2)
    h, w = stack.shape[:2]
    r = np.arange(-half_window, half_window + 1, dtype=float)
    dx, dy = (a.ravel() for a in np.meshgrid(r, r))
    half = (dy > 0) | ((dy == 0) & (dx > 0))  # d and -d give the same equation
    dx, dy = dx[half], dy[half]
    wgt = np.exp(-(dx ** 2 + dy ** 2) / float(half_window) ** 2)
    q = q0.copy()
    ok = np.ones(len(q), bool)
    step = np.zeros_like(q)
    for _ in range(iterations):
        ok &= np.all((q >= half_window + 1) & (q <= np.array([w, h]) - half_window - 2), axis=1)
        qs = np.where(ok[:, None], q, half_window + 1.0)
        xp, yp = qs[:, :1] + dx, qs[:, 1:] + dy
        xm, ym = qs[:, :1] - dx, qs[:, 1:] - dy
        sp, sm = _bilinear(stack, xp, yp), _bilinear(stack, xm, ym)
        p, m = sp[..., 0], sm[..., 0]
        s = p + m
        # columns: the difference's change with q, then the illumination's four terms
        jac = np.stack([sp[..., 1] - sm[..., 1], sp[..., 2] - sm[..., 2],
                        dx * s, dy * s, np.broadcast_to(dx, s.shape), np.broadcast_to(dy, s.shape)], -1)
        jw = jac * wgt[:, None]
        a = np.einsum("nkp,nkq->npq", jw, jac)
        b = np.einsum("nkp,nk->np", jw, p - m)
        good = np.linalg.cond(a) < 1e12
        ok &= good
        a[~good] = np.eye(6)
        step = -np.linalg.solve(a, b[..., None])[:, :2, 0]
        q = np.where(ok[:, None], q + step, q)
        if not np.any(ok) or np.max(np.abs(step[ok])) < _SYM_TOL:
            break
    ok &= np.all(np.abs(step) < 10 * _SYM_TOL, axis=1) & np.all(np.isfinite(q), axis=1)
    return np.where(ok[:, None], q, q0), ok


def detect_board(image, board, symmetric=False):
    """Detect a board's corners in one image (BGR or gray, 8 or 16 bit).

    symmetric : refine a ChArUco board's corners to their point of symmetry after
        CharucoDetector (`refine_charuco_corners`); off by default (the module's docstring
        says why). A chessboard's corners always are, whatever it says.
    Returns a BoardDetection (its ``symmetric`` says whether the corners were refined so);
    when nothing is found, ``ids`` is empty (not an error).
    """
    import cv2

    gray = _gray(image)
    h, w = gray.shape[:2]
    empty_m = (np.zeros(0, int), np.zeros((0, 4, 2)))
    if board.type == "charuco":
        cc, ci, mc, mi = _detect_charuco(gray, board)
        m_ids = np.zeros(0, int) if mi is None else np.asarray(mi, int).ravel()
        m_corners = np.zeros((0, 4, 2)) if mc is None or len(mc) == 0 else np.asarray(mc, float).reshape(-1, 4, 2)
        if ci is None or cc is None or len(ci) == 0:
            return BoardDetection(np.zeros(0, int), np.zeros((0, 2)), (w, h), m_ids, m_corners, bool(symmetric))
        ids = np.asarray(ci, int).ravel()
        corners = np.asarray(cc, float).reshape(-1, 2)
        if symmetric:
            corners, _ = refine_charuco_corners(gray, corners, ids, board.inner_corners[0])
        order = np.argsort(ids)
        return BoardDetection(ids[order], corners[order], (w, h), m_ids, m_corners, bool(symmetric))
    cols, rows = board.inner_corners
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    found, corners = cv2.findChessboardCornersSB(gray, (cols, rows), flags=flags)
    if not found or corners is None:
        found, corners = cv2.findChessboardCorners(gray, (cols, rows),
                                                   flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found or corners is None:
        return BoardDetection(np.zeros(0, int), np.zeros((0, 2)), (w, h), *empty_m, True)
    corners = refine_chessboard_corners(gray, np.asarray(corners, float).reshape(-1, 2), cols, rows)
    return BoardDetection(np.arange(cols * rows), corners, (w, h), *empty_m, True)
