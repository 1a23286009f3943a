"""A camera's intrinsics as one parameter vector, its Jacobian and its covariance.

The intrinsics of a `Camera` are the vector ``theta = (fx, fy, cx, cy, dist...)`` [px for the
first four, the distortion coefficients unitless], named by `intrinsic_names` (OpenCV's
order; the skew, where a camera has one, is held fixed). A calibration estimates theta with
a covariance (`toolkit.board.calibrate`); every estimate made later with the camera (a
board pose, a pencil's orientation, a fulcrum) inherits that uncertainty. To first order
an estimate ``y(theta)`` has the extra covariance ``G C_theta G^T`` with ``G = dy/dtheta``,
which is what mrcal does for its projection uncertainty; `propagate` adds it.

`IntrinsicsCovariance` is that covariance with its parameter names, as the camera file's
statistics carry it (``camera.meta["cov_intrinsics"]``, `META_KEY`) and as
`pencilcal calibrate --report` writes it: ``{"names": [...], "cov": P x P}``.

Example
-------
>>> import numpy as np
>>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [-0.1, 0.01, 0, 0])
>>> intrinsic_names(cam)
['fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'p1', 'p2']
>>> with_intrinsics(cam, intrinsics_vector(cam) + [1.0, 0, 0, 0, 0, 0, 0, 0]).fx
501.0
>>> J = jacobian_pixels_wrt_intrinsics(cam, np.array([[0.1, -0.2]]))
>>> J.shape, bool(np.allclose(J[0, :, 2:4], np.eye(2)))
((1, 2, 8), True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError

from . import splined as _spl
from .model import Camera

__all__ = ["META_KEY", "OPENCV_DIST_NAMES", "FISHEYE_DIST_NAMES", "model_intrinsic_names", "intrinsic_names",
           "intrinsics_vector", "with_intrinsics", "jacobian_pixels_wrt_intrinsics", "IntrinsicsCovariance",
           "camera_intrinsics_covariance", "propagate"]

#: The camera meta key (and calibration report key) of the intrinsics' covariance.
META_KEY = "cov_intrinsics"
#: OpenCV's distortion coefficients, in its order.
OPENCV_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "taux", "tauy")
#: Kannala-Brandt's coefficients (cv2.fisheye).
FISHEYE_DIST_NAMES = ("k1", "k2", "k3", "k4")
# step of the central differences of the distortion [coefficient units]; the K part is exact
_DIST_STEP = 1e-6
# relative asymmetry and negative eigenvalue (of the largest) a covariance may have
_SYMMETRY_TOL = 1e-9
_PSD_TOL = 1e-9


def model_intrinsic_names(model, n_dist):
    """Names of the intrinsic parameters of a lens model with `n_dist` coefficients.

    >>> model_intrinsic_names("fisheye", 4)
    ['fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'k3', 'k4']
    """
    if _spl.is_splined(model):
        return ["fx", "fy", "cx", "cy"] + _spl.control_names(_spl.splined_config(model))
    dist = FISHEYE_DIST_NAMES if model == "fisheye" else OPENCV_DIST_NAMES[:n_dist]
    return ["fx", "fy", "cx", "cy"] + list(dist)


def intrinsic_names(camera):
    """Names (P,) of `camera`'s intrinsic parameters, in the order of `intrinsics_vector`."""
    return model_intrinsic_names(camera.model, camera.dist.size)


def intrinsics_vector(camera):
    """theta (P,) = (fx, fy, cx, cy [px], dist... [unitless]) of `camera`."""
    return np.r_[camera.fx, camera.fy, camera.cx, camera.cy, camera.dist]


def with_intrinsics(camera, theta):
    """A copy of `camera` with the intrinsics `theta` (P,) (skew and meta kept)."""
    th = np.asarray(theta, float).reshape(-1)
    if th.size != 4 + camera.dist.size:
        raise InputError(f"{th.size} intrinsics for a camera with {4 + camera.dist.size}")
    K = np.array(camera.K, float)
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = th[:4]
    return Camera(camera.model, camera.width, camera.height, K, th[4:], meta=camera.meta)


def jacobian_pixels_wrt_intrinsics(camera, xy):
    """d(raw pixel) / d(theta) at fixed normalised points.

    Parameters
    ----------
    camera : Camera
    xy : (..., 2) array_like
        Normalised (undistorted) coordinates, X/Z and Y/Z.

    Returns
    -------
    (..., 2, P) ndarray
        [px per unit of each parameter], columns in `intrinsic_names` order. The K columns
        are exact; the distortion columns are central differences (step 1e-6), exact to
        ~1e-10 relative (a splined model's control points: exact, the spline's weights).
    """
    xy = np.asarray(xy, float)
    xd = camera.distort_normalized(xy)
    n = camera.dist.size
    J = np.zeros(xy.shape[:-1] + (2, 4 + n))
    J[..., 0, 0] = xd[..., 0]
    J[..., 1, 1] = xd[..., 1]
    J[..., 0, 2] = 1.0
    J[..., 1, 3] = 1.0
    if camera.spline is not None:
        u, _ = _spl.stereographic(np.concatenate([xy, np.ones_like(xy[..., :1])], -1))
        _, _, idx, w = _spl.correction(camera.spline, camera.dist, u, jac=True)
        flat = J.reshape(-1, 2, 4 + n)
        rows = np.arange(flat.shape[0])[:, None]
        for a, f in ((0, camera.fx), (1, camera.fy)):
            flat[rows, a, 4 + idx.reshape(-1, 16, 2)[..., a]] = f * w.reshape(-1, 16)
        return flat.reshape(J.shape)
    if n:
        A = np.asarray(camera.K, float)[:2, :2]
        th = intrinsics_vector(camera)
        for j in range(n):
            step = np.zeros_like(th)
            step[4 + j] = _DIST_STEP
            plus = with_intrinsics(camera, th + step).distort_normalized(xy)
            minus = with_intrinsics(camera, th - step).distort_normalized(xy)
            J[..., :, 4 + j] = (plus - minus) @ A.T / (2.0 * _DIST_STEP)
    return J


@dataclass(frozen=True, eq=False)
class IntrinsicsCovariance:
    """The covariance of a camera's intrinsics, with the names of its rows.

    names : tuple of str
        As `intrinsic_names` (fx, fy, cx, cy, then the distortion coefficients).
    cov : (P, P) ndarray
        [px^2 for fx..cy, unitless^2 for the coefficients]; rows of parameters a
        calibration held fixed are zero.
    source : str
        Where it came from (a file name), for the records.
    """

    names: tuple
    cov: np.ndarray
    source: str = "camera"

    @property
    def std(self):
        """(P,) standard deviations, in the order of `names`."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    def to_dict(self):
        """``{"names": [...], "cov": P x P}`` (the camera meta and report record)."""
        return {"names": list(self.names), "cov": self.cov.tolist()}

    @classmethod
    def from_dict(cls, d, source="camera"):
        """From ``{"names", "cov"}``; InputError naming `source` unless the names are
        strings and cov a finite, symmetric, positive semi-definite P x P matrix."""
        if not isinstance(d, dict) or not isinstance(d.get("names"), (list, tuple)) or "cov" not in d:
            raise InputError(f"{source}: '{META_KEY}' must be an object with 'names' and 'cov'")
        names = tuple(d["names"])
        if not all(isinstance(n, str) for n in names):
            raise InputError(f"{source}: '{META_KEY}' names must be strings")
        try:
            C = np.array(d["cov"], dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{source}: '{META_KEY}' cov must be numbers") from None
        P = len(names)
        if C.shape != (P, P):
            raise InputError(f"{source}: '{META_KEY}' cov must be {P} x {P}, got shape {C.shape}")
        if not np.all(np.isfinite(C)):
            raise InputError(f"{source}: '{META_KEY}' cov has a non-finite entry")
        scale = max(float(np.abs(C).max()), 1e-300)
        if np.abs(C - C.T).max() > _SYMMETRY_TOL * scale:
            raise InputError(f"{source}: '{META_KEY}' cov is not symmetric")
        C = 0.5 * (C + C.T)
        if P and np.linalg.eigvalsh(C).min() < -_PSD_TOL * scale:
            raise InputError(f"{source}: '{META_KEY}' cov is not positive semi-definite")
        return cls(names, C, str(source))

    def for_camera(self, camera):
        """cov (P, P) in `camera`'s parameter order; InputError when the names differ
        (a covariance of another lens model or coefficient count)."""
        want = intrinsic_names(camera)
        if list(self.names) != want:
            raise InputError(f"{self.source}: the intrinsics' covariance is over {', '.join(self.names)} but the "
                             f"camera has {', '.join(want)}")
        return self.cov


def camera_intrinsics_covariance(camera, source="camera"):
    """The `IntrinsicsCovariance` a camera file's statistics carry (``meta["cov_intrinsics"]``),
    checked against the camera, or None when it carries none."""
    d = (camera.meta or {}).get(META_KEY)
    if d is None:
        return None
    c = IntrinsicsCovariance.from_dict(d, source)
    c.for_camera(camera)
    return c


def propagate(G, cov):
    """G cov G^T for G (..., M, P) and cov (P, P): the covariance an estimate y with
    dy/dtheta = G inherits from theta's. Returns (..., M, M), symmetric.

    >>> propagate(np.array([[2.0, 0.0]]), np.eye(2)).tolist()
    [[4.0]]
    """
    G = np.asarray(G, float)
    out = G @ np.asarray(cov, float) @ np.swapaxes(G, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))
