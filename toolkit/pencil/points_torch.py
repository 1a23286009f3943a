"""Raw pixel points and segments to normalised coordinates and angles, batched in torch.

`undistort_points_torch` inverts the OpenCV lens model for many points at once (kornia's
undistortion, polished by Newton steps); `segment_angles_torch` turns raw pixel segments
into the normalised image angles that `estimator_torch.fit_pencils_torch` fits. Pinhole and
OpenCV-model cameras only (fisheye lenses: `Camera.normalized_from_pixels`). torch and
kornia are optional (torch_backend.py).

Example
-------
>>> import numpy as np
>>> seg = np.array([[[100.0, 100.0, 200.0, 100.0]]])          # (1, 1, 4) raw pixels
>>> K = [[800.0, 0, 100.0], [0, 800.0, 100.0], [0, 0, 1]]
>>> round(float(segment_angles_torch(seg, K)["angles"][0, 0]), 12)
0.0
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.torch_backend import as_tensor, import_torch, resolve_device, torch_dtype

__all__ = ["undistort_points_torch", "segment_angles_torch"]


def _camera_arrays(camera_or_K, dist):
    """(K (..., 3, 3) [px], dist (..., n)) of a pinhole/opencv Camera or of K and dist as given."""
    from pencilcal.toolkit.camera.model import Camera

    if isinstance(camera_or_K, Camera):
        if camera_or_K.model == "fisheye":
            raise InputError("segment_angles_torch handles pinhole and opencv cameras; for fisheye lenses "
                             "use Camera.normalized_from_pixels")
        K = np.asarray(camera_or_K.K, float)
        d = np.asarray(camera_or_K.dist, float)
    else:
        K = np.asarray(camera_or_K, float)
        d = np.zeros(0) if dist is None else np.asarray(dist, float)
    if K.shape[-2:] != (3, 3):
        raise InputError(f"K must be (..., 3, 3), got {K.shape}")
    if d.shape[-1] not in (0, 4, 5, 8, 12, 14):
        raise InputError(f"OpenCV distortion takes 4, 5, 8, 12 or 14 coefficients, got {d.shape[-1]}")
    return K, d


def undistort_points_torch(px, camera_or_K, dist=None, *, device="cpu", dtype="float64", num_iters=20,
                           newton=3):
    """Raw pixels of an OpenCV-model camera to normalised coordinates, in batches.

    Parameters
    ----------
    px : (..., M, 2) [px] raw pixels (OpenCV convention, pixel centres at integers).
    camera_or_K : a pinhole/opencv `Camera`, or K (3, 3) / (..., 3, 3) [px].
    dist : (n,) or (..., n) OpenCV coefficients (n = 4, 5, 8, 12, 14) when K is given.
    num_iters : fixed-point iterations of ``kornia.geometry.calibration.undistort_points``.
    newton : Newton steps polishing that start on ``kornia...distort_points`` (Jacobian
        by autograd): kornia's fixed point alone stops at ~1e-4 px near the corners of
        strongly distorted lenses and has no convergence test (kornia#4285).

    Returns
    -------
    (..., M, 2) tensor of normalised coordinates; NaN where the distortion model is not
    inverted to 1e-10 (float64; 1e-4 in float32) normalised units. Unlike
    `Camera.normalized_from_pixels` no fold check is made: far outside the lens model's
    invertible part the answer may be a root beyond the fold.

    Example
    -------
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("opencv", 1920, 1080, [[1500.0, 0, 959.5], [0, 1500.0, 539.5], [0, 0, 1]],
    ...              [-0.3, 0.12, 0.001, -0.002, 0.0])
    >>> xy = undistort_points_torch([[0.0, 0.0], [1919.0, 1079.0]], cam).numpy()
    >>> bool(abs(xy - cam.normalized_from_pixels([[0.0, 0.0], [1919.0, 1079.0]])).max() < 1e-11)
    True
    """
    torch, kornia = import_torch()
    dev = resolve_device(device)
    dt = torch_dtype(torch, dtype)
    K, d = _camera_arrays(camera_or_K, dist)
    p = px.to(dev, dt) if isinstance(px, torch.Tensor) else as_tensor(torch, px, dt, dev)
    if p.shape[-1] != 2 or p.ndim < 2:
        raise InputError(f"pixels must be (..., M, 2), got {tuple(p.shape)}")
    Kt = torch.as_tensor(np.array(K, dtype=float), dtype=dt, device=dev)
    # K^-1 including the skew (kornia ignores K[0, 1])
    yd = (p[..., 1] - Kt[..., 1, 2, None]) / Kt[..., 1, 1, None]
    xd = (p[..., 0] - Kt[..., 0, 2, None] - Kt[..., 0, 1, None] * yd) / Kt[..., 0, 0, None]
    target = torch.stack([xd, yd], -1)
    if d.shape[-1] == 0:
        return target
    D = torch.as_tensor(np.array(d, dtype=float), dtype=dt, device=dev)
    eye = torch.eye(3, dtype=dt, device=dev)
    calib = kornia.geometry.calibration
    with torch.no_grad():
        xy = calib.undistort_points(target, eye, D, eye, num_iters=num_iters)
    for _ in range(newton):
        with torch.enable_grad():
            q = xy.detach().requires_grad_(True)
            f = calib.distort_points(q, eye, D, eye)
            gx = torch.autograd.grad(f[..., 0].sum(), q, retain_graph=True)[0]
            gy = torch.autograd.grad(f[..., 1].sum(), q)[0]
        with torch.no_grad():
            e = f.detach() - target
            det = gx[..., 0] * gy[..., 1] - gx[..., 1] * gy[..., 0]
            dx = (gy[..., 1] * e[..., 0] - gx[..., 1] * e[..., 1]) / det
            dy = (-gy[..., 0] * e[..., 0] + gx[..., 0] * e[..., 1]) / det
            xy = xy - torch.stack([dx, dy], -1)
    with torch.no_grad():
        err = (calib.distort_points(xy, eye, D, eye) - target).norm(dim=-1)
        tol = (1e-4 if dt == torch.float32 else 1e-10) * (1.0 + target.norm(dim=-1))
        return torch.where((err <= tol)[..., None], xy, torch.nan)


def segment_angles_torch(segments, camera_or_K, dist=None, vertex=None, *, device="cpu", dtype="float64",
                         num_iters=20, newton=3):
    """Normalised image angles of raw pixel segments, batched (OpenCV lens model).

    Parameters
    ----------
    segments : (..., M, 4) [px] raw segments ``[x1, y1, x2, y2]``.
    camera_or_K, dist : as `undistort_points_torch`.
    vertex : (..., 2) normalised vertex or None. When given each segment is oriented away
        from it (as `orient.orient_segments` does), so the angles are spoke directions;
        otherwise the angle runs from the first to the second end point.

    Returns
    -------
    dict of tensors: ``angles`` (..., M) [rad] in normalised coordinates, ready for
    `fit_pencils_torch`; ``p1, p2`` (..., M, 2) the undistorted end points; ``ok``
    (..., M) bool, False where an end point could not be undistorted.

    Example
    -------
    >>> import numpy as np
    >>> seg = np.array([[[100.0, 100.0, 200.0, 200.0]]])
    >>> K = [[800.0, 0, 100.0], [0, 800.0, 100.0], [0, 0, 1]]
    >>> out = segment_angles_torch(seg, K)          # pinhole: the pixel angle itself
    >>> round(float(np.degrees(out["angles"][0, 0])), 9)
    45.0
    """
    torch, _ = import_torch()
    dt = torch_dtype(torch, dtype)
    s = segments if isinstance(segments, torch.Tensor) else as_tensor(torch, segments, torch.float64, "cpu")
    if s.shape[-1] != 4 or s.ndim < 2:
        raise InputError(f"segments must be (..., M, 4) as [x1, y1, x2, y2], got {tuple(s.shape)}")
    pts = s.reshape(s.shape[:-1] + (2, 2)).reshape(s.shape[:-2] + (-1, 2))
    xy = undistort_points_torch(pts, camera_or_K, dist, device=device, dtype=dtype, num_iters=num_iters,
                                newton=newton)
    xy = xy.reshape(s.shape[:-1] + (2, 2))
    p1, p2 = xy[..., 0, :], xy[..., 1, :]
    t = p2 - p1
    if vertex is not None:
        v = vertex.to(xy.device, dt) if isinstance(vertex, torch.Tensor) else torch.as_tensor(
            np.array(vertex, dtype=float), dtype=dt, device=xy.device)
        v = v[..., None, :]
        s1, s2 = ((p1 - v) * t).sum(-1), ((p2 - v) * t).sum(-1)
        away = torch.where(s2.abs() >= s1.abs(), 1.0, -1.0).to(dt)
        t = t * away[..., None]
    ang = torch.atan2(t[..., 1], t[..., 0])
    ok = torch.isfinite(ang)
    return {"angles": ang, "p1": p1, "p2": p2, "ok": ok}
