"""Camera intrinsics: the one home for projection and undistortion in pencilcal.

A `Camera` holds the intrinsics of one camera in OpenCV's conventions and maps between
camera-frame points, *normalised* image coordinates and raw (distorted) pixels. Every
method is vectorised numpy and broadcasts over leading dimensions.

Conventions
-----------
- Camera frame: OpenCV (x right, y down, z forward); frames.py.
- Pixels: OpenCV's. Pixel (0, 0) is the *centre* of the top-left pixel, so the image spans
  [-0.5, width - 0.5] x [-0.5, height - 0.5]. COLMAP puts that centre at (0.5, 0.5): its
  principal point is ours + 0.5 (camera_io.py converts). mrcal uses ours.
- Normalised coordinates ``xy`` are the z = 1 plane *before* distortion: xy = (X/Z, Y/Z).
- ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; the skew ``s`` is usually 0.
  Pixels are ``K @ (x_d, y_d, 1)`` with ``(x_d, y_d)`` the distorted normalised point.

Models
------
``"pinhole"``
    No distortion; ``dist`` has shape (0,).
``"opencv"``
    OpenCV's radial-tangential model with 4, 5, 8, 12 or 14 coefficients in OpenCV's order
    ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [taux tauy]]]]`` (rational radial term,
    thin prism, tilted sensor), exactly as ``cv2.projectPoints``.
``"fisheye"``
    Kannala-Brandt with ``k1..k4`` exactly as ``cv2.fisheye``:
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` with
    ``theta`` the angle off the optical axis. `project` and `rays_from_pixels` handle
    directions beyond 90 degrees; normalised coordinates cannot represent them (NaN).

Nothing here silently returns a wrong number: points behind a pinhole/opencv camera
project to NaN, and pixels whose undistortion does not converge to ~1e-12 (normalised
units) on the invertible part of the lens model come back as NaN.

Example
-------
>>> import numpy as np
>>> K = [[1500.0, 0, 959.5], [0, 1500.0, 539.5], [0, 0, 1]]
>>> cam = Camera("opencv", 1920, 1080, K, [-0.3, 0.12, 0.0, 0.0])
>>> px = cam.project([0.2, -0.1, 2.0])
>>> px.round(6).tolist()
[1108.940312, 464.779844]
>>> ray = cam.rays_from_pixels(px)
>>> np.allclose(ray, np.array([0.2, -0.1, 2.0]) / np.linalg.norm([0.2, -0.1, 2.0]), atol=1e-12)
True
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.errors import InputError

from . import splined as _spl

__all__ = ["Camera", "mean_focal", "MODELS", "OPENCV_COEFFICIENT_COUNTS", "tilt_matrices", "K_RATIO_LIMIT"]

#: Lens models and the coefficient counts each accepts.
MODELS = {"pinhole": (0,), "opencv": (4, 5, 8, 12, 14), "fisheye": (4,)}
OPENCV_COEFFICIENT_COUNTS = MODELS["opencv"]

# Newton on the distortion: iterations, and the residual (normalised units, relative to
# 1 + |target|) a solution must reach to be returned rather than NaN.
# Sanity limits on a camera's image size: OpenCV's own image limits (2^20 px a side, 2^30
# pixels), far beyond any real sensor (a 100 MP sensor is 1e8 px).
MAX_SIDE_PX = 1 << 20
MAX_CAMERA_PIXELS = 1 << 30
# K's entries relative to the image's larger side: focal lengths within 1/1000 and 1000
# times it (fields of view from 0.06 deg to beyond any fisheye), the principal point and the
# skew within 1000 sides. Past them no lens exists and the numbers overflow (fx = 1e308
# made every segment's direction 0/0).
K_RATIO_LIMIT = 1000.0
_NEWTON_ITERATIONS = 50
_NEWTON_TOL = 1e-14
_ACCEPT_TOL = 1e-11
# Samples along the segment from the principal point to a solution on which the lens
# model must stay locally invertible; a root beyond a fold of the model is rejected.
_FOLD_SAMPLES = np.linspace(0.0, 1.0, 9)[1:]


def mean_focal(K) -> float:
    """The geometric mean focal length sqrt(fx fy) of a camera matrix [px].

    The one scale between pixels and radians (a pixel near the centre subtends about 1 / f
    rad) where x and y differ: a square pixel's focal length, the area-preserving mean.

    K: (3, 3) camera matrix (or anything indexable as one).

    >>> mean_focal([[400.0, 0, 0], [0, 900.0, 0], [0, 0, 1]])
    600.0
    """
    return float(np.sqrt(float(K[0][0]) * float(K[1][1])))


def _check_k_scale(K, side):
    """InputError when K's focal lengths, principal point or skew are out of proportion to
    the image (`K_RATIO_LIMIT`)."""
    lo, hi = side / K_RATIO_LIMIT, side * K_RATIO_LIMIT
    for name, v in (("fx", K[0, 0]), ("fy", K[1, 1])):
        if not lo <= v <= hi:
            raise InputError(f"K: {name} = {float(v):.6g} px is outside {lo:.6g}..{hi:.6g} px (1/{K_RATIO_LIMIT:g} to "
                             f"{K_RATIO_LIMIT:g} times the image's larger side, {side} px): no lens gives it")
    for name, v in (("cx", K[0, 2]), ("cy", K[1, 2]), ("skew", K[0, 1])):
        if not abs(v) <= hi:
            raise InputError(f"K: {name} = {float(v):.6g} px is beyond +-{hi:.6g} px ({K_RATIO_LIMIT:g} times the "
                             f"image's larger side, {side} px)")


def tilt_matrices(taux, tauy):
    """OpenCV's tilted-sensor projection (computeTiltProjectionMatrix) and its inverse.

    taux, tauy: tilt angles [rad] (coefficients 13 and 14 of the opencv model).
    Returns (T, T_inv), both (3, 3): distorted normalised points (x, y, 1) map to
    ``T @ (x, y, 1)``, divided by its third component.
    """
    ctx, stx = np.cos(taux), np.sin(taux)
    cty, sty = np.cos(tauy), np.sin(tauy)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, ctx, stx], [0.0, -stx, ctx]])
    rot_y = np.array([[cty, 0.0, -sty], [0.0, 1.0, 0.0], [sty, 0.0, cty]])
    rot_xy = rot_y @ rot_x
    proj_z = np.array([[rot_xy[2, 2], 0.0, -rot_xy[0, 2]], [0.0, rot_xy[2, 2], -rot_xy[1, 2]], [0.0, 0.0, 1.0]])
    inv = 1.0 / rot_xy[2, 2]
    inv_proj_z = np.array([[inv, 0.0, inv * rot_xy[0, 2]], [0.0, inv, inv * rot_xy[1, 2]], [0.0, 0.0, 1.0]])
    return proj_z @ rot_xy, rot_xy.T @ inv_proj_z


def _count_words(counts):
    words = [str(c) for c in counts]
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


def _last_dim(a, n, what):
    a = np.asarray(a, dtype=float)
    if a.shape[-1:] != (n,):
        raise InputError(f"{what} must have shape (..., {n}), got {a.shape}")
    return a


def _readonly(a):
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Camera:
    """Intrinsics of one camera: lens model, image size, K and distortion coefficients.

    Parameters
    ----------
    model : {"pinhole", "opencv", "fisheye"}
    width, height : int
        Image size [pixels].
    K : (3, 3) array_like
        ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` [pixels]; fx, fy > 0.
    dist : (N,) array_like
        Distortion coefficients: N = 0 (pinhole), 4/5/8/12/14 (opencv), 4 (fisheye).
    meta : dict, optional
        Calibration statistics and other metadata (rms_px, std_intrinsics, ...), carried
        through the file formats that can hold it. Not part of equality.

    Raises
    ------
    InputError
        On any invalid value, with a one-line message (readers prefix the file name).

    Notes
    -----
    K and dist are stored as read-only float64 arrays. Two cameras are equal when model,
    size, K and dist are exactly equal.

    Example
    -------
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> cam.project([[0.0, 0.0, 1.0], [0.1, 0.2, 1.0]]).tolist()
    [[319.5, 239.5], [369.5, 339.5]]
    >>> cam.size, cam.fx
    ((640, 480), 500.0)
    """

    model: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))
    meta: dict | None = None

    def __post_init__(self):
        model = self.model
        spline = None
        if _spl.is_splined(model):
            spline = _spl.splined_config(model)
            model = spline.name
            object.__setattr__(self, "model", model)
        elif not isinstance(model, str) or model not in MODELS:
            raise InputError(f"unknown camera model {model!r}; expected one of {sorted(MODELS)} or "
                             f"{_spl.PREFIX}_order=3_Nx=.._Ny=.._fov_x_deg=..")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer, float, np.floating)) \
                    or not np.isfinite(v) or v != int(v):
                raise InputError(f"image {name} must be a whole number of pixels, got {v!r}")
            if not 0 < int(v) <= MAX_SIDE_PX:
                raise InputError(f"image {name} must be positive and at most {MAX_SIDE_PX} px, got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.width * self.height > MAX_CAMERA_PIXELS:
            raise InputError(f"image size {self.width}x{self.height} is over the limit of {MAX_CAMERA_PIXELS:,} pixels "
                             "(no real camera comes near it: is the file right?)")
        try:
            K = np.array(self.K, dtype=float)
        except (TypeError, ValueError):
            raise InputError("K must be a 3x3 matrix of numbers") from None
        if K.shape != (3, 3):
            raise InputError(f"K must be 3x3, got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise InputError("K has a non-finite entry")
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise InputError(f"K must have fx > 0 and fy > 0, got fx={float(K[0, 0])!r}, fy={float(K[1, 1])!r}")
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise InputError(f"K must be upper triangular with bottom row [0, 0, 1], got {K.tolist()}")
        _check_k_scale(K, max(self.width, self.height))
        if self.dist is None:
            dist = np.zeros(0)
        else:
            try:
                dist = np.array(self.dist, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise InputError("distortion coefficients must be numbers") from None
        counts = (spline.parameters,) if spline is not None else MODELS[model]
        if dist.size not in counts:
            hint = " (use model 'pinhole' for none)" if model == "opencv" and dist.size == 0 else ""
            raise InputError(
                f"camera model {model!r} takes {_count_words(counts)} distortion coefficients, "
                f"got {dist.size}{hint}")
        if not np.all(np.isfinite(dist)):
            raise InputError("distortion coefficients have a non-finite entry")
        if model == "opencv" and dist.size == 14 and not np.all(np.abs(dist[12:]) < np.pi / 2):
            raise InputError(f"sensor tilt angles taux, tauy must be within +-pi/2 rad, got {dist[12:].tolist()}")
        if self.meta is not None and not isinstance(self.meta, dict):
            raise InputError(f"camera meta must be a dict, got {type(self.meta).__name__}")
        object.__setattr__(self, "K", _readonly(K))
        object.__setattr__(self, "dist", _readonly(dist))
        object.__setattr__(self, "meta", None if self.meta is None else dict(self.meta))
        k = np.zeros(14)
        if spline is None:
            k[: dist.size] = dist
        object.__setattr__(self, "_k", k)
        # only k1, k2, k3 (the common lens): `_rtp` then skips the terms that are exact zeros
        object.__setattr__(self, "_radial_only", not np.any(k[[2, 3, 5, 6, 7, 8, 9, 10, 11]]))
        tilt = tilt_matrices(k[12], k[13]) if model == "opencv" and dist.size == 14 else None
        object.__setattr__(self, "_tilt", tilt)
        object.__setattr__(self, "_spline", spline)

    # ------------------------------------------------------------------ basics
    def __eq__(self, other):
        if not isinstance(other, Camera):
            return NotImplemented
        return (self.model == other.model and self.size == other.size
                and np.array_equal(self.K, other.K) and self.dist.shape == other.dist.shape
                and np.array_equal(self.dist, other.dist))

    def __hash__(self):
        # tolist() hashes 0.0 and -0.0 alike, as __eq__ compares them
        return hash((self.model, self.size, tuple(self.K.ravel().tolist()), tuple(self.dist.tolist())))

    def __reduce__(self):
        # rebuild through __init__ so copies and pickles are validated and read-only again
        return (Camera, (self.model, self.width, self.height, self.K, self.dist, self.meta))

    def __repr__(self):
        return (f"Camera(model={self.model!r}, width={self.width}, height={self.height}, "
                f"K={self.K.tolist()}, dist={self.dist.tolist()})")

    @property
    def fx(self) -> float:
        """Focal length along x [pixels]."""
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        """Focal length along y [pixels]."""
        return float(self.K[1, 1])

    @property
    def f_mean(self) -> float:
        """Geometric mean focal length sqrt(fx fy) [pixels] (`mean_focal`)."""
        return mean_focal(self.K)

    @property
    def cx(self) -> float:
        """Principal point x [pixels, OpenCV convention]."""
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        """Principal point y [pixels, OpenCV convention]."""
        return float(self.K[1, 2])

    @property
    def skew(self) -> float:
        """K[0, 1] [pixels]; 0 for almost every camera."""
        return float(self.K[0, 1])

    @property
    def spline(self):
        """The `splined.SplineConfig` of a splined camera, else None."""
        return self._spline

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) [pixels]."""
        return (self.width, self.height)

    # ------------------------------------------------------------ K and its inverse
    def _apply_K(self, xd):
        K = self.K
        u = K[0, 0] * xd[..., 0] + K[0, 1] * xd[..., 1] + K[0, 2]
        v = K[1, 1] * xd[..., 1] + K[1, 2]
        return np.stack([u, v], -1)

    def _apply_K_inv(self, px):
        K = self.K
        y = (px[..., 1] - K[1, 2]) / K[1, 1]
        x = (px[..., 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return np.stack([x, y], -1)

    # -------------------------------------------------- opencv distortion and Jacobian
    def _rtp(self, x, y, jac=False):
        """Radial, tangential and thin-prism distortion (no tilt), as OpenCV orders it."""
        if self._radial_only:
            return self._radial(x, y, jac)
        k = self._k
        r2 = x * x + y * y
        r4 = r2 * r2
        r6 = r4 * r2
        num = 1.0 + k[0] * r2 + k[1] * r4 + k[4] * r6
        den = 1.0 + k[5] * r2 + k[6] * r4 + k[7] * r6
        radial = num / den
        xd = x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x) + k[8] * r2 + k[9] * r4
        yd = y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y + k[10] * r2 + k[11] * r4
        if not jac:
            return xd, yd, None
        dnum = k[0] + 2.0 * k[1] * r2 + 3.0 * k[4] * r4
        dden = k[5] + 2.0 * k[6] * r2 + 3.0 * k[7] * r4
        drad = (dnum * den - num * dden) / (den * den)  # d radial / d r2
        px_ = k[8] + 2.0 * k[9] * r2  # d prism_x / d r2
        py_ = k[10] + 2.0 * k[11] * r2
        j00 = radial + 2.0 * x * x * drad + 2.0 * k[2] * y + 6.0 * k[3] * x + 2.0 * x * px_
        j01 = 2.0 * x * y * drad + 2.0 * k[2] * x + 2.0 * k[3] * y + 2.0 * y * px_
        j10 = 2.0 * x * y * drad + 2.0 * k[2] * x + 2.0 * k[3] * y + 2.0 * x * py_
        j11 = radial + 2.0 * y * y * drad + 6.0 * k[2] * y + 2.0 * k[3] * x + 2.0 * y * py_
        return xd, yd, (j00, j01, j10, j11)

    def _radial(self, x, y, jac=False):
        """`_rtp` of a lens with only k1, k2, k3: the same operations in the same order less
        the terms that are exact zeros (no denominator, tangential or prism terms), so the
        same numbers to the last bit, at half the cost of an undistortion (undistorting a
        frame's few line ends calls it dozens of times on small arrays).

        >>> cam = Camera("opencv", 640, 480, [[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], [-0.3, 0.1, 0, 0, 0.02])
        >>> x, y = np.linspace(-0.6, 0.6, 7), np.linspace(0.5, -0.4, 7)
        >>> fast = cam._rtp(x, y, jac=True)
        >>> object.__setattr__(cam, "_radial_only", False)  # the general terms, for comparison
        >>> general = cam._rtp(x, y, jac=True)
        >>> all(np.array_equal(a, b) for a, b in zip((*fast[:2], *fast[2]), (*general[:2], *general[2])))
        True
        """
        k0, k1, k4 = self._k[0], self._k[1], self._k[4]
        r2 = x * x + y * y
        r4 = r2 * r2
        radial = 1.0 + k0 * r2 + k1 * r4
        if k4:
            radial = radial + k4 * (r4 * r2)
        xd, yd = x * radial, y * radial
        if not jac:
            return xd, yd, None
        drad = k0 + 2.0 * k1 * r2
        if k4:
            drad = drad + 3.0 * k4 * r4
        j01 = 2.0 * x * y * drad
        return xd, yd, (radial + 2.0 * x * x * drad, j01, j01, radial + 2.0 * y * y * drad)

    def _apply_tilt(self, xd, yd, jac=None):
        T = self._tilt[0]
        v0 = T[0, 0] * xd + T[0, 1] * yd + T[0, 2]
        v1 = T[1, 0] * xd + T[1, 1] * yd + T[1, 2]
        v2 = T[2, 0] * xd + T[2, 1] * yd + T[2, 2]
        # OpenCV divides by 1 where the third component vanishes
        inv = 1.0 / np.where(v2 == 0, 1.0, v2)
        out_x, out_y = v0 * inv, v1 * inv
        if jac is None:
            return out_x, out_y, None
        t00 = (T[0, 0] - out_x * T[2, 0]) * inv
        t01 = (T[0, 1] - out_x * T[2, 1]) * inv
        t10 = (T[1, 0] - out_y * T[2, 0]) * inv
        t11 = (T[1, 1] - out_y * T[2, 1]) * inv
        j00, j01, j10, j11 = jac
        return out_x, out_y, (t00 * j00 + t01 * j10, t00 * j01 + t01 * j11,
                              t10 * j00 + t11 * j10, t10 * j01 + t11 * j11)

    # ------------------------------------------------------ fisheye distortion
    def _theta_d(self, theta, deriv=False):
        k = self._k
        t2 = theta * theta
        poly = 1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))
        td = theta * poly
        if not deriv:
            return td, None
        dtd = 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))
        return td, dtd

    def _fisheye_from_points(self, p):
        """Distorted normalised coordinates of camera-frame points for the fisheye model."""
        X, Y, Z = p[..., 0], p[..., 1], p[..., 2]
        rho = np.hypot(X, Y)
        theta = np.arctan2(rho, Z)
        td, _ = self._theta_d(theta)
        # on the axis the direction is irrelevant in front and undefined behind
        scale = np.where(rho > 0, td / np.where(rho > 0, rho, 1.0), np.where(Z > 0, 0.0, np.nan))
        return np.stack([X * scale, Y * scale], -1)

    # ------------------------------------------------------------- public maps
    def distort_normalized(self, xy):
        """Distorted normalised coordinates (before K) of normalised points.

        xy: (..., 2) on the z = 1 plane. Returns (..., 2), including the sensor tilt of
        14-coefficient opencv models.
        """
        xy = _last_dim(xy, 2, "normalised points")
        if self.model == "pinhole":
            return xy.copy()
        if self.model == "fisheye":
            return self._fisheye_from_points(np.concatenate([xy, np.ones_like(xy[..., :1])], -1))
        if self._spline is not None:
            return self._splined_from_points(np.concatenate([xy, np.ones_like(xy[..., :1])], -1))
        xd, yd, _ = self._rtp(xy[..., 0], xy[..., 1])
        if self._tilt is not None:
            xd, yd, _ = self._apply_tilt(xd, yd)
        return np.stack([xd, yd], -1)

    def pixels_from_normalized(self, xy):
        """Raw pixels of normalised points: distortion, then K.

        Parameters
        ----------
        xy : (..., 2) array_like
            Normalised coordinates (X/Z, Y/Z), undistorted.

        Returns
        -------
        (..., 2) ndarray
            Pixels [OpenCV convention, pixel (0, 0) is the centre of the top-left pixel].
        """
        return self._apply_K(self.distort_normalized(xy))

    def project(self, points_cam):
        """Raw pixels of camera-frame points, as cv2.projectPoints / cv2.fisheye.projectPoints.

        Parameters
        ----------
        points_cam : (..., 3) array_like
            Points (or directions) in the camera frame, any length unit.

        Returns
        -------
        (..., 2) ndarray
            Pixels. NaN for points with Z <= 0 under the pinhole and opencv models (OpenCV
            would mirror them into the image); the fisheye model projects every direction
            except straight backwards, beyond 90 degrees too.

        Example
        -------
        >>> cam = Camera("fisheye", 800, 800, [[300.0, 0, 399.5], [0, 300.0, 399.5], [0, 0, 1]], [0, 0, 0, 0])
        >>> cam.project([[1.0, 0.0, 0.0], [1.0, 0.0, -1.0]]).round(6).tolist()   # 90 and 135 deg
        [[870.738898, 399.5], [1106.358347, 399.5]]
        """
        p = _last_dim(points_cam, 3, "points")
        if self.model == "fisheye":
            return self._apply_K(self._fisheye_from_points(p))
        if self._spline is not None:
            return self._apply_K(self._splined_from_points(p))
        Z = p[..., 2]
        front = Z > 0
        Zs = np.where(front, Z, np.nan)
        xy = p[..., :2] / Zs[..., None]
        return self.pixels_from_normalized(xy)

    def jacobian_pixels_from_normalized(self, xy):
        """Analytic Jacobian d(pixel)/d(xy) of `pixels_from_normalized`.

        xy: (..., 2) normalised coordinates. Returns (..., 2, 2) [pixels per normalised
        unit], rows (u, v), columns (x, y).
        """
        xy = _last_dim(xy, 2, "normalised points")
        x, y = xy[..., 0], xy[..., 1]
        if self.model == "pinhole":
            one, zero = np.ones_like(x), np.zeros_like(x)
            jac = (one, zero, zero, one)
        elif self.model == "opencv":
            xd, yd, jac = self._rtp(x, y, jac=True)
            if self._tilt is not None:
                _, _, jac = self._apply_tilt(xd, yd, jac)
        elif self._spline is not None:
            p = np.concatenate([xy, np.ones_like(xy[..., :1])], -1)
            u, du_dp = _spl.stereographic(p)
            _, Jc, _, _ = _spl.correction(self._spline, self.dist, u, jac=True)
            Jd = (np.eye(2) + Jc) @ du_dp[..., :, :2]
            jac = (Jd[..., 0, 0], Jd[..., 0, 1], Jd[..., 1, 0], Jd[..., 1, 1])
        else:
            jac = self._fisheye_jacobian(x, y)
        j00, j01, j10, j11 = jac
        K = self.K
        J = np.empty(xy.shape[:-1] + (2, 2))
        J[..., 0, 0] = K[0, 0] * j00 + K[0, 1] * j10
        J[..., 0, 1] = K[0, 0] * j01 + K[0, 1] * j11
        J[..., 1, 0] = K[1, 1] * j10
        J[..., 1, 1] = K[1, 1] * j11
        return J

    def _splined_from_points(self, p):
        """u + du(u) (..., 2) of camera-frame points under the splined model."""
        u, _ = _spl.stereographic(p)
        return u + _spl.correction(self._spline, self.dist, u)[0]

    def _splined_u(self, d):
        """Solve u + du(u) = d (N, 2) for u by damped Newton (steps halved until the
        residual falls); NaN where it does not converge or the model folds there (det of
        d(u + du)/du not positive)."""
        cfg, ctrl = self._spline, self.dist

        def residual(u):
            e = u + _spl.correction(cfg, ctrl, u)[0] - d
            n = np.hypot(e[:, 0], e[:, 1])
            return e, np.where(np.isfinite(n), n, np.inf)

        u = d.copy()
        scale = 1.0 + np.hypot(d[:, 0], d[:, 1])
        with np.errstate(all="ignore"):
            e, err = residual(u)
            for _ in range(_NEWTON_ITERATIONS):
                active = err > _NEWTON_TOL * scale
                if not np.any(active):
                    break
                J = _spl.correction(cfg, ctrl, u, jac=True)[1] + np.eye(2)
                step = np.linalg.solve(np.where(np.isfinite(J), J, 0.0) + 1e-300 * np.eye(2), e[..., None])[..., 0]
                t = np.ones(len(u))
                todo = active.copy()
                for _ in range(31):
                    cand = u - t[:, None] * step
                    ec, errc = residual(cand)
                    ok = todo & (errc < err)
                    u = np.where(ok[:, None], cand, u)
                    e = np.where(ok[:, None], ec, e)
                    err = np.where(ok, errc, err)
                    todo &= ~ok
                    if not np.any(todo):
                        break
                    t = np.where(todo, 0.5 * t, t)
                if np.all(todo | ~active):
                    break               # no point improved: at round-off or stuck
            J = _spl.correction(cfg, ctrl, u, jac=True)[1] + np.eye(2)
            det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
            ok = (err <= _ACCEPT_TOL * scale) & (det > 0)
        u[~ok] = np.nan
        return u

    def _fisheye_jacobian(self, x, y):
        # x_d = s(r) (x, y) with s = theta_d(atan r) / r, so J = s I + (s'(r) / r) (x, y)(x, y)^T
        r = np.hypot(x, y)
        small = r < 1e-8
        rs = np.where(small, 1.0, r)
        theta = np.arctan(rs)
        td, dtd = self._theta_d(theta, deriv=True)
        s = td / rs
        ds_over_r = (dtd / (1.0 + rs * rs) - s) / (rs * rs)
        # series at r -> 0: s = 1 + (k1 - 1/3) r^2 + ..., s'/r -> 2 (k1 - 1/3)
        s = np.where(small, 1.0, s)
        ds_over_r = np.where(small, 2.0 * (self._k[0] - 1.0 / 3.0), ds_over_r)
        return (s + ds_over_r * x * x, ds_over_r * x * y, ds_over_r * x * y, s + ds_over_r * y * y)

    # ------------------------------------------------------------ undistortion
    def _undistort_rtp(self, target):
        """Solve rtp(x) = target (N, 2); NaN where it does not converge. A lens with k1, k2,
        k3 only is solved along each point's radius (`_undistort_radial`), the points it
        fails for by the general damped Newton (`_undistort_general`)."""
        if not self._radial_only:
            return self._undistort_general(target)
        out = self._undistort_radial(target)
        bad = np.isnan(out[:, 0])
        if np.any(bad):
            out[bad] = self._undistort_general(target[bad])
        return out

    def _undistort_radial(self, target):
        """`_undistort_general` of a lens with k1, k2, k3 only, in one dimension: the point
        stays on its ray from the centre, so r (1 + k1 r^2 + k2 r^4 + k3 r^6) = r_d is solved
        for r by Newton from r = r_d (a few vectorised steps instead of the 2-D iteration's
        fixed-point start, backtracking and bookkeeping: a frame's few line ends are undistorted
        several times, ~0.25 ms a call before). Accepted as the general solver accepts (the
        2-D residual within _ACCEPT_TOL, no fold between the centre and the point), NaN
        elsewhere; the same roots, to the general solver's tolerance (~1e-14).

        >>> cam = Camera("opencv", 640, 480, [[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], [-0.3, 0.1, 0, 0, 0.02])
        >>> d = np.array([[0.0, 0.0], [0.3, -0.2], [-0.55, 0.4]])
        >>> bool(np.abs(cam._undistort_radial(d) - cam._undistort_general(d)).max() < 1e-13)
        True
        """
        tx, ty = target[:, 0], target[:, 1]
        k0, k1, k4 = self._k[0], self._k[1], self._k[4]
        rd = np.hypot(tx, ty)
        with np.errstate(all="ignore"):
            r = rd.copy()
            for _ in range(_NEWTON_ITERATIONS):
                r2 = r * r
                f = r * (1.0 + r2 * (k0 + r2 * (k1 + r2 * k4))) - rd
                step = f / (1.0 + r2 * (3.0 * k0 + r2 * (5.0 * k1 + r2 * 7.0 * k4)))
                r = r - step
                if not np.any(np.abs(step) > _NEWTON_TOL * (1.0 + rd)):  # NaN steps end it too
                    break
            s = np.where(rd > 0, r / np.where(rd > 0, rd, 1.0), 1.0)
            x, y = tx * s, ty * s
            xd, yd, _ = self._radial(x, y)
            err = np.hypot(xd - tx, yd - ty)
            ok = (err <= _ACCEPT_TOL * (1.0 + rd)) & (r >= 0) & self._invertible_along(x, y)
        out = np.stack([x, y], -1)
        out[~ok] = np.nan
        return out

    def _undistort_general(self, target):
        """Solve rtp(x) = target (N, 2) by damped Newton; NaN where it does not converge."""
        tx, ty = target[:, 0], target[:, 1]
        scale = 1.0 + np.hypot(tx, ty)

        def error(x, y, sel):
            xd, yd, _ = self._rtp(x, y)
            e = np.hypot(xd - tx[sel], yd - ty[sel])
            return np.where(np.isfinite(e), e, np.inf)

        k = self._k
        with np.errstate(all="ignore"):
            # Start from the better of the distorted point itself and OpenCV's fixed-point
            # iterate x = (x_d - delta(x)) / radial(x), which is good for mild distortion.
            fx_, fy_ = tx.copy(), ty.copy()
            for _ in range(5):
                r2 = fx_ * fx_ + fy_ * fy_
                xd, yd, _ = self._rtp(fx_, fy_)
                radial = (1.0 + k[0] * r2 + k[1] * r2 * r2 + k[4] * r2 ** 3) / (
                    1.0 + k[5] * r2 + k[6] * r2 * r2 + k[7] * r2 ** 3)
                fx_ = (tx - (xd - fx_ * radial)) / radial
                fy_ = (ty - (yd - fy_ * radial)) / radial
            err = error(tx, ty, slice(None))
            err_fp = error(fx_, fy_, slice(None))
            better = err_fp < err
            x = np.where(better, fx_, tx)
            y = np.where(better, fy_, ty)
            err = np.where(better, err_fp, err)

            active = err > _NEWTON_TOL * scale
            for _ in range(_NEWTON_ITERATIONS):
                idx = np.nonzero(active)[0]
                if idx.size == 0:
                    break
                xi, yi = x[idx], y[idx]
                xd, yd, (j00, j01, j10, j11) = self._rtp(xi, yi, jac=True)
                ex, ey = xd - tx[idx], yd - ty[idx]
                det = j00 * j11 - j01 * j10
                sx = (j11 * ex - j01 * ey) / det
                sy = (j00 * ey - j10 * ex) / det
                # Backtracking keeps Newton from overshooting at the image corners; once the
                # residual is at round-off level no step can lower it, so stop halving there.
                best_x, best_y, best_e = xi, yi, err[idx]
                todo = np.ones(idx.size, bool)
                t = np.ones(idx.size)
                for _ in range(31):
                    cx_, cy_ = xi - t * sx, yi - t * sy
                    e = error(cx_, cy_, idx)
                    ok = todo & (e < best_e)
                    best_x = np.where(ok, cx_, best_x)
                    best_y = np.where(ok, cy_, best_y)
                    best_e = np.where(ok, e, best_e)
                    todo &= ~ok & (best_e > _ACCEPT_TOL * scale[idx])
                    if not np.any(todo):
                        break
                    t = np.where(todo, 0.5 * t, t)
                improved = best_e < err[idx]
                x[idx], y[idx], err[idx] = best_x, best_y, best_e
                active[idx] = improved & (best_e > _NEWTON_TOL * scale[idx])
            ok = (err <= _ACCEPT_TOL * scale) & self._invertible_along(x, y)
        out = np.stack([x, y], -1)
        out[~ok] = np.nan
        return out

    def _invertible_along(self, x, y):
        """True where det J > 0 from the principal point out to (x, y): the root lies on
        the branch of the model that contains the centre, not beyond a fold."""
        t = _FOLD_SAMPLES[:, None]
        _, _, (j00, j01, j10, j11) = self._rtp(t * x, t * y, jac=True)
        return np.all(j00 * j11 - j01 * j10 > 0, axis=0)

    def _fisheye_theta(self, rd):
        """theta >= 0 with theta_d(theta) = rd (N,), Newton in one dimension; NaN if none."""
        theta = np.minimum(rd, 3.0)  # theta_d ~ theta near the centre
        with np.errstate(all="ignore"):
            for _ in range(_NEWTON_ITERATIONS):
                td, dtd = self._theta_d(theta, deriv=True)
                step = (td - rd) / dtd
                theta_new = np.clip(theta - step, 0.0, np.pi)
                if np.all(~np.isfinite(step) | (np.abs(step) <= _NEWTON_TOL * (1.0 + theta))):
                    theta = theta_new
                    break
                theta = theta_new
            td, _ = self._theta_d(theta)
            ok = np.abs(td - rd) <= _ACCEPT_TOL * (1.0 + rd)
            ok &= theta < np.pi
            # theta_d must increase from 0 to theta (no fold on the way)
            samples = _FOLD_SAMPLES[:, None] * theta
            ok &= np.all(self._theta_d(samples, deriv=True)[1] > 0, axis=0)
        return np.where(ok, theta, np.nan)

    def _distorted_from_pixels(self, px):
        """Pixels (N, 2) to distorted normalised coordinates before any sensor tilt."""
        d = self._apply_K_inv(px)
        if self._tilt is not None:
            Ti = self._tilt[1]
            v0 = Ti[0, 0] * d[:, 0] + Ti[0, 1] * d[:, 1] + Ti[0, 2]
            v1 = Ti[1, 0] * d[:, 0] + Ti[1, 1] * d[:, 1] + Ti[1, 2]
            v2 = Ti[2, 0] * d[:, 0] + Ti[2, 1] * d[:, 1] + Ti[2, 2]
            d = np.stack([v0 / v2, v1 / v2], -1)
        return d

    def normalized_from_pixels(self, px):
        """Undistort raw pixels to normalised coordinates (z = 1 plane).

        Inverts the lens model by damped Newton iterations with the analytic Jacobian,
        started from the better of the distorted point and OpenCV's fixed-point iterate,
        to a residual of ~1e-12 normalised units (about 1e-9 px): much tighter than
        cv2.undistortPoints with its default 5 iterations. A lens with k1, k2, k3 only
        is inverted along each point's radius, in one dimension, to the same roots.

        Parameters
        ----------
        px : (..., 2) array_like
            Raw pixels [OpenCV convention].

        Returns
        -------
        (..., 2) ndarray
            Normalised coordinates. NaN where the iteration does not converge, where the
            only solutions lie beyond a fold of the model (outside its invertible part),
            and for fisheye pixels 90 degrees or more off the axis.

        Example
        -------
        >>> cam = Camera("opencv", 1920, 1080, [[1500.0, 0, 959.5], [0, 1500.0, 539.5], [0, 0, 1]],
        ...              [-0.3, 0.12, 0.001, -0.002, 0.0])
        >>> px = [[0.0, 0.0], [1919.0, 1079.0]]
        >>> float(abs(cam.pixels_from_normalized(cam.normalized_from_pixels(px)) - px).max()) < 1e-9
        True
        """
        px = _last_dim(px, 2, "pixels")
        shape = px.shape
        flat = px.reshape(-1, 2)
        d = self._distorted_from_pixels(flat)
        if self.model == "pinhole":
            out = d
        elif self.model == "opencv":
            out = self._undistort_rtp(d)
        elif self._spline is not None:
            out = _spl.normalized_from_stereographic(self._splined_u(d))
        else:
            rd = np.hypot(d[:, 0], d[:, 1])
            theta = self._fisheye_theta(rd)
            with np.errstate(all="ignore"):
                r = np.where(theta < np.pi / 2, np.tan(theta), np.nan)
                scale = np.where(rd > 0, r / np.where(rd > 0, rd, 1.0), 1.0)
            out = d * scale[:, None]
        return out.reshape(shape)

    def rays_from_pixels(self, px):
        """Unit viewing rays (camera frame) of raw pixels.

        px: (..., 2) pixels. Returns (..., 3) unit vectors; for fisheye lenses this
        includes rays beyond 90 degrees off the axis (z < 0). NaN where undistortion fails.
        """
        px = _last_dim(px, 2, "pixels")
        if self._spline is not None:
            u = self._splined_u(self._distorted_from_pixels(px.reshape(-1, 2)))
            return _spl.rays_from_stereographic(u).reshape(px.shape[:-1] + (3,))
        if self.model != "fisheye":
            xy = self.normalized_from_pixels(px)
            v = np.concatenate([xy, np.ones_like(xy[..., :1])], -1)
            return v / np.linalg.norm(v, axis=-1, keepdims=True)
        flat = px.reshape(-1, 2)
        d = self._distorted_from_pixels(flat)
        rd = np.hypot(d[:, 0], d[:, 1])
        theta = self._fisheye_theta(rd)
        with np.errstate(all="ignore"):
            dirs = np.where(rd[:, None] > 0, d / np.where(rd > 0, rd, 1.0)[:, None], 0.0)
        st = np.sin(theta)
        rays = np.stack([dirs[:, 0] * st, dirs[:, 1] * st, np.cos(theta)], -1)
        return rays.reshape(px.shape[:-1] + (3,))

    def undistort_pixels(self, px):
        """Ideal pinhole pixels ``K @ (x, y, 1)`` of raw pixels (same K, no distortion).

        px: (..., 2) raw pixels. Returns (..., 2); NaN where `normalized_from_pixels` is.
        """
        return self._apply_K(self.normalized_from_pixels(px))

    def normalized_and_ideal(self, px):
        """(`normalized_from_pixels`, `undistort_pixels`) of raw pixels px (..., 2) from one
        inversion of the lens model: the same numbers as the two calls (each point is
        solved on its own), at the cost of one.

        >>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
        >>> xy, ideal = cam.normalized_and_ideal([[10.0, 20.0], [600.0, 400.0]])
        >>> bool(np.array_equal(ideal, cam.undistort_pixels([[10.0, 20.0], [600.0, 400.0]])))
        True
        """
        xy = self.normalized_from_pixels(px)
        return xy, self._apply_K(xy)

    def distort_pixels(self, ideal_px):
        """Raw pixels of ideal pinhole pixels; the inverse of `undistort_pixels`.

        ideal_px: (..., 2) pixels of the undistorted image with the same K. Returns (..., 2).
        """
        ideal = _last_dim(ideal_px, 2, "pixels")
        return self.pixels_from_normalized(self._apply_K_inv(ideal))
