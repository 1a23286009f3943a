"""The exact estimator in torch: batched fits of millions of pencils, on the CPU or a GPU.

`fit_pencils_torch` is `estimator.fit_pencil` written for torch, so that Monte Carlo maps
(validation/sensitivity.py), sequences of many frames and planning studies run at
hundreds of thousands of fits per second. It follows the numpy estimator step by step
and agrees with it to 1e-6 deg in float64 (median 1e-13 deg; the largest differences are
where numpy's LM stops on its relative-cost test; tests/toolkit/test_torch_estimator.py):

1. Closed-form start in the virtual camera that looks along the vertex ray: a batched
   DLT of the 2x2 matrix A in ``(cos b_k, sin b_k) ~ A (cos theta_k, sin theta_k)``
   (``torch.linalg.eigh`` of the 4x4 normal matrix), the analytic signed 2x2 SVD, and
   cos(gamma) = s2 / s1 (GEOMETRY.md, "The exact estimator").
2. Levenberg-Marquardt on wrapped, weighted line residuals (period pi, the rule of
   `angles.wrap_line`), with left perturbations ``R <- expm([delta]x) R`` (rotation
   vectors converted by kornia), per-pencil damping and masks; converged pencils leave
   the working set, so stragglers do not make everybody iterate.
3. Covariance (J^T W J)^-1 with the vertex covariance carried in, tilt and normal sigma.
4. Frontal likelihood-ratio test (chi-square, 2 dof, level `estimator.DETECTION_LEVEL`)
   for ``detectable``; the twin ``R' = Rot(v_d, pi) R Rot(z, pi)``, ordered as numpy
   does (the normal closer to the optical axis first).

torch and kornia are optional (``pip install torch==2.13.0 && pip install -e ".[torch]"``);
they are imported only when a function here runs. Without them every entry point raises
`TorchUnavailableError` (an `InputError` and an `ImportError`) whose one-line message says
how to install them. `torch_available()` tells without raising.

Three things differ from numpy on purpose:

- ``converged`` is judged when a pencil leaves the LM. The numpy loop keeps multiplying the
  damping of pencils that stopped early while others iterate, so in large batches with a
  slow straggler it can report converged=False for pencils that did converge.
- ``strict=False`` fits what can be fitted and marks the rest (``ok`` False, NaN fields)
  instead of raising for the whole batch.
- Lines that do not determine a pencil (fewer than three distinct directions) are
  caught when the second-smallest eigenvalue of the DLT matrix is below 1e-12 of the
  largest; numpy's 1e-20 lies below rounding and catches them only by luck of sign.

Angles are radians, image angles in normalised camera coordinates (z = 1 plane, after
undistortion); `segment_angles_torch` turns raw pixel segments of OpenCV-model cameras into
such angles in batches (kornia's undistortion, polished by Newton steps).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.frames import rotation_from_rotvec, rotation_angle
>>> from pencilcal.toolkit.pencil import image_angles
>>> R_true = rotation_from_rotvec([0.5, -0.2, 0.1])
>>> theta = np.radians(np.arange(8) * 20.0)
>>> vertex = np.array([[0.1, -0.05]])                       # (B, 2), normalised
>>> a = image_angles(R_true, vertex, theta)                  # (B, N)
>>> fit = fit_pencils_torch(a, theta, vertex, sigma=np.radians(0.1), output="numpy")
>>> err = min(rotation_angle(fit["R_cam_from_target"][0], R_true),
...           rotation_angle(fit["R_twin"][0], R_true))
>>> bool(np.degrees(err) < 1e-8), bool(fit["detectable"][0])
(True, True)
"""
from __future__ import annotations

import contextlib
import math
import time

import numpy as np

from .errors import EstimationError, InputError
from .estimator import PencilFit, _CHI2_2, _MAX_VERTEX, _MIN_COS

__all__ = [
    "INSTALL_HINT",
    "TorchUnavailableError",
    "torch_available",
    "require_torch",
    "resolve_device",
    "wrap_line_torch",
    "fit_pencils_torch",
    "to_pencil_fit",
    "undistort_points_torch",
    "segment_angles_torch",
    "benchmark_batched",
]

INSTALL_HINT = 'pip install torch==2.13.0 && pip install -e ".[torch]"'

# pencils per chunk: 16384 x 8 lines keeps the temporaries (1 MB each) near the cache,
# and each chunk runs on one core (_single_threaded); chunks run on `workers` threads
_CHUNK_CPU = 16384
_CHUNK_CUDA = 1 << 18


class TorchUnavailableError(InputError, ImportError):
    """torch/kornia missing, or a CUDA device asked for where there is none.

    An `InputError` (the command line prints its one-line message and exits 1) and an
    `ImportError` (``except ImportError`` works as for any optional dependency).
    """


def torch_available() -> bool:
    """True when torch and kornia can be imported (the ``[torch]`` extra is installed)."""
    try:
        _import_torch()
        return True
    except TorchUnavailableError:
        return False


def _import_torch():
    try:
        import torch  # noqa: F401
        import kornia  # noqa: F401
    except ImportError as e:
        missing = getattr(e, "name", None) or "torch"
        raise TorchUnavailableError(f"{missing} is not installed; the torch path needs it: {INSTALL_HINT}") from None
    return torch, kornia


def require_torch(device="cpu"):
    """Import torch (and kornia) and check `device`; return the torch module.

    Raises TorchUnavailableError with a one-line message naming the install command when
    torch/kornia are missing or when ``device`` is a CUDA device that torch cannot use.
    """
    torch, _ = _import_torch()
    resolve_device(device)
    return torch


def resolve_device(device="cpu"):
    """``torch.device`` for "cpu", "cuda", "cuda:1" or a torch.device; raises
    TorchUnavailableError when CUDA is asked for and is not available."""
    torch, _ = _import_torch()
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as e:
        raise InputError(f"unknown device {device!r}: {e}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        build = "a CPU-only build" if torch.version.cuda is None else f"CUDA {torch.version.cuda}, but no GPU is visible"
        raise TorchUnavailableError(
            f"device {device!r} asked for, but torch {torch.__version__} is {build}: "
            f"use --device cpu, or install a CUDA build of torch on a machine with a GPU")
    return dev


def _tensor(torch, v, dt, dev):
    """A tensor from array_like (copied: numpy views may be read-only, which torch warns about)."""
    try:
        arr = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError("expected an array of numbers") from None
    return torch.as_tensor(arr, dtype=dt, device=dev)


def _dtype(torch, dtype):
    if dtype is None:
        return torch.float64
    if isinstance(dtype, str):
        if dtype not in ("float64", "float32"):
            raise InputError(f"dtype must be 'float64' or 'float32', got {dtype!r}")
        return getattr(torch, dtype)
    if dtype not in (torch.float64, torch.float32):
        raise InputError(f"dtype must be torch.float64 or torch.float32, got {dtype!r}")
    return dtype


def wrap_line_torch(angle):
    """`angles.wrap_line` for tensors: line angles (period pi) into (-pi/2, pi/2].

    The same rule, written with torch.remainder (sign of the divisor, as np.remainder), so
    it runs on the tensor's device; tests check it against `angles.wrap_line`.
    """
    import torch

    h = math.pi / 2.0
    return h - torch.remainder(h - angle, math.pi)


# ----------------------------------------------------------------------------------------
# model, written out on (B, N) tensors (no small matmuls: they are slow in batches)


def _model(R, x0, x1, ct, st, jac=True):
    """Image angles (B, N) and, with `jac`, d alpha/d delta (3 x (B, N)) and d alpha/d
    vertex (2 x (B, N)) for R (B, 3, 3), vertex columns x0, x1 (B, 1), spokes ct, st."""
    dx = R[:, 0, 0, None] * ct + R[:, 0, 1, None] * st
    dy = R[:, 1, 0, None] * ct + R[:, 1, 1, None] * st
    dz = R[:, 2, 0, None] * ct + R[:, 2, 1, None] * st
    wx = dx - x0 * dz
    wy = dy - x1 * dz
    import torch

    alpha = torch.atan2(wy, wx)
    if not jac:
        return alpha, None, None
    inv = 1.0 / (wx * wx + wy * wy)
    gx = -wy * inv
    gy = wx * inv
    u2 = -(gx * x0 + gy * x1)
    J = (dy * u2 - dz * gy, dz * gx - dx * u2, dx * gy - dy * gx)
    Jx = (-dz * gx, -dz * gy)
    return alpha, J, Jx


def _virtual_rotation(torch, x0, x1):
    """Q (B, 3, 3) with Q (x, y, 1) ~ (0, 0, 1): estimator._virtual_rotation in torch."""
    n = torch.sqrt(1.0 + x0 * x0 + x1 * x1)
    vx, vy, c = x0 / n, x1 / n, 1.0 / n
    kx, ky = vy, -vx
    f = 1.0 / (1.0 + c)
    one = torch.ones_like(c)
    rows = [
        [one - f * ky * ky, f * kx * ky, ky],
        [f * kx * ky, one - f * kx * kx, -kx],
        [-ky, kx, c],
    ]
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def _zxz(torch, phi, cos_g, sin_g, theta):
    """Rz(phi) Rx(gamma) Rz(theta) for (B,) tensors, written out."""
    cp, sp, ct, st = torch.cos(phi), torch.sin(phi), torch.cos(theta), torch.sin(theta)
    rows = [
        [cp * ct - sp * cos_g * st, -cp * st - sp * cos_g * ct, sp * sin_g],
        [sp * ct + cp * cos_g * st, -sp * st + cp * cos_g * ct, -cp * sin_g],
        [sin_g * st, sin_g * ct, cos_g],
    ]
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def _closed_form(torch, bx, by, ct, st, w, Q, oriented, low_precision):
    """Batched DLT + analytic signed SVD; returns (R0 (B, 3, 3), bad (B,) bool)."""
    nb = torch.sqrt(bx * bx + by * by)
    cb, sb = bx / nb, by / nb
    sw = torch.sqrt(w)
    rows = torch.stack(torch.broadcast_tensors(sb * ct * sw, sb * st * sw, -cb * ct * sw, -cb * st * sw), -1)
    M = rows.transpose(-1, -2) @ rows
    evals, evecs = torch.linalg.eigh(M)
    # a unique pencil needs a one-dimensional null space. Rounding leaves the second
    # eigenvalue of a degenerate M at ~1e-16 (float32: ~1e-7) of the largest, of either
    # sign: numpy's 1e-20 catches it only when the rounding happens to be negative
    bad = evals[:, 1] <= (1e-6 if low_precision else 1e-12) * evals[:, 3]
    h = evecs[:, :, 0]
    a, b, c, d = h[:, 0], h[:, 1], h[:, 2], h[:, 3]
    if oriented:
        agree = (w * ((a[:, None] * ct + b[:, None] * st) * cb + (c[:, None] * ct + d[:, None] * st) * sb)).sum(-1)
        sgn = torch.where(agree < 0, -1.0, 1.0).to(a.dtype)
        a, b, c, d = a * sgn, b * sgn, c * sgn, d * sgn
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    q, r = torch.hypot(E, H), torch.hypot(F, G)
    a1, a2 = torch.atan2(G, F), torch.atan2(H, E)
    theta0, phi = (a2 - a1) / 2, (a2 + a1) / 2
    tiny = torch.finfo(q.dtype).tiny
    cos_g = torch.clamp((q - r) / torch.clamp(q + r, min=tiny), min=float(_MIN_COS), max=1.0)
    sin_g = torch.sqrt(1.0 - cos_g * cos_g)
    R = Q.transpose(-1, -2) @ _zxz(torch, phi, cos_g, sin_g, theta0)
    return R, bad


def _sym3_solve(h00, h01, h02, h11, h12, h22, g0, g1, g2):
    """Solve a batch of symmetric positive definite 3x3 systems by LDL^T, written out."""
    d0 = h00
    l10 = h01 / d0
    l20 = h02 / d0
    d1 = h11 - l10 * h01
    l21 = (h12 - l20 * h01) / d1
    d2 = h22 - l20 * h02 - l21 * l21 * d1
    y0 = g0
    y1 = g1 - l10 * y0
    y2 = g2 - l20 * y0 - l21 * y1
    z2 = y2 / d2
    z1 = y1 / d1 - l21 * z2
    z0 = y0 / d0 - l10 * z1 - l20 * z2
    return z0, z1, z2


def _refine(torch, kornia, R, a, ct, st, x0, x1, sw, max_iter, tol, low_precision):
    """LM of estimator.refine_pencil on one chunk; returns (R, cost, converged, nit, it)."""
    B = R.shape[0]
    dev, dt = R.device, R.dtype
    rot = kornia.geometry.conversions.axis_angle_to_rotation_matrix
    rel = 1e-5 if low_precision else 1e-14
    tiny = torch.finfo(dt).tiny
    # full-chunk state, written back when the working set shrinks
    R_all = R.clone()
    cost_all = torch.empty(B, dtype=dt, device=dev)
    lam_all = torch.empty(B, dtype=dt, device=dev)
    nit_all = torch.zeros(B, dtype=torch.int32, device=dev)
    idx = None  # None: the working set is the whole chunk
    per_pencil_spokes = ct.shape[0] == B and B > 1

    alpha, J, _ = _model(R, x0, x1, ct, st)
    r = sw * wrap_line_torch(a - alpha)
    cost = (r * r).sum(-1)
    lam = torch.full((B,), 1e-4, dtype=dt, device=dev)
    active = torch.ones(B, dtype=torch.bool, device=dev)
    nit = torch.zeros(B, dtype=torch.int32, device=dev)
    n_set = B
    it = 0
    for it in range(1, max_iter + 1):
        nit = nit + active.to(torch.int32)
        Jw0, Jw1, Jw2 = J[0] * sw, J[1] * sw, J[2] * sw
        h00 = (Jw0 * Jw0).sum(-1)
        h01 = (Jw0 * Jw1).sum(-1)
        h02 = (Jw0 * Jw2).sum(-1)
        h11 = (Jw1 * Jw1).sum(-1)
        h12 = (Jw1 * Jw2).sum(-1)
        h22 = (Jw2 * Jw2).sum(-1)
        g0, g1, g2 = (Jw0 * r).sum(-1), (Jw1 * r).sum(-1), (Jw2 * r).sum(-1)
        floor = 1e-12 * (h00 + h11 + h22) + tiny
        lf = lam * floor
        s0, s1, s2 = _sym3_solve(h00 * (1.0 + lam) + lf, h01, h02, h11 * (1.0 + lam) + lf, h12,
                                 h22 * (1.0 + lam) + lf, g0, g1, g2)
        step = torch.stack([s0, s1, s2], -1) * active[:, None]
        R_new = rot(step) @ R
        alpha_n, J_n, _ = _model(R_new, x0, x1, ct, st)
        r_n = sw * wrap_line_torch(a - alpha_n)
        cost_n = (r_n * r_n).sum(-1)
        better = (cost_n <= cost) & active
        R = torch.where(better[:, None, None], R_new, R)
        bm = better[:, None]
        J = tuple(torch.where(bm, jn, j) for jn, j in zip(J_n, J))
        r = torch.where(bm, r_n, r)
        small = (step * step).sum(-1) < tol * tol
        stalled = better & ((cost - cost_n) <= rel * cost)
        if low_precision:
            # float32 rounding: a cost that neither falls nor rises has converged too
            stalled = stalled | (~better & ((cost_n - cost).abs() <= rel * cost))
        cost = torch.where(better, cost_n, cost)
        lam = torch.where(active, lam * torch.where(better, 0.1, 10.0).to(dt), lam)
        active = active & ~(small | stalled | (lam > 1e10))
        n_active = int(active.sum())
        if n_active == 0:
            break
        if n_active < n_set // 2 and n_set > 64:
            # shrink the working set to the pencils still iterating
            sel = torch.nonzero(active).squeeze(1)
            full_idx = torch.arange(B, device=dev) if idx is None else idx
            R_all[full_idx] = R
            cost_all[full_idx] = cost
            lam_all[full_idx] = lam
            nit_all[full_idx] = nit
            idx = full_idx[sel]
            R, cost, lam, nit, r = R[sel], cost[sel], lam[sel], nit[sel], r[sel]
            J = tuple(j[sel] for j in J)
            a, sw, x0, x1 = a[sel], sw[sel], x0[sel], x1[sel]
            if per_pencil_spokes:
                ct, st = ct[sel], st[sel]
            active = active[sel]
            n_set = n_active
    full_idx = torch.arange(B, device=dev) if idx is None else idx
    R_all[full_idx] = R
    cost_all[full_idx] = cost
    lam_all[full_idx] = lam
    nit_all[full_idx] = nit
    return R_all, cost_all, lam_all <= 1e10, nit_all, it


def _covariance(torch, R, x0, x1, J, Jx, w, Cx):
    """estimator._covariance in torch, the 3x3 algebra written out. x0, x1: (B, 1)."""
    wJ = [w * j for j in J]
    h00, h01, h02 = (wJ[0] * J[0]).sum(-1), (wJ[0] * J[1]).sum(-1), (wJ[0] * J[2]).sum(-1)
    h11, h12, h22 = (wJ[1] * J[1]).sum(-1), (wJ[1] * J[2]).sum(-1), (wJ[2] * J[2]).sum(-1)
    ridge = 1e-14 * (h00 + h11 + h22)
    a, b, c, d, e, f = h00 + ridge, h01, h02, h11 + ridge, h12, h22 + ridge
    A00, A01, A02 = d * f - e * e, c * e - b * f, b * e - c * d
    A11, A12, A22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A00 + b * A01 + c * A02
    Hinv = torch.stack([torch.stack([A00, A01, A02], -1), torch.stack([A01, A11, A12], -1),
                        torch.stack([A02, A12, A22], -1)], -2) / det[:, None, None]
    n = R[:, :, 2]
    x0, x1 = x0[:, 0], x1[:, 0]
    nv = torch.sqrt(1.0 + x0 * x0 + x1 * x1)
    v = torch.stack([x0, x1, torch.ones_like(x0)], -1) / nv[:, None]
    nxv = torch.linalg.cross(n, v, dim=-1)
    sin_g = torch.clamp(torch.sqrt((nxv * nxv).sum(-1)), min=1e-12)
    g_rot = -nxv / sin_g[:, None]
    var_tilt = (g_rot[:, :, None] * Hinv * g_rot[:, None, :]).sum((-1, -2))
    cov = Hinv
    if Cx is not None:
        K = torch.stack([torch.stack([(wj * jx).sum(-1) for jx in Jx], -1) for wj in wJ], -2)  # (B, 3, 2)
        G = -Hinv @ K
        cov = cov + G @ Cx @ G.transpose(-1, -2)
        eye = torch.eye(3, dtype=R.dtype, device=R.device)
        P = (eye - v[:, :, None] * v[:, None, :])[:, :, :2] / nv[:, None, None]
        g_x = (g_rot[:, None, :] @ G)[:, 0] - (n[:, None, :] @ P)[:, 0] / sin_g[:, None]
        var_tilt = var_tilt + (g_x[:, None, :] @ Cx @ g_x[:, :, None])[:, 0, 0]
    # trace((I - n n^T) cov (I - n n^T)) = trace(cov) - n^T cov n
    var_normal = torch.diagonal(cov, dim1=-2, dim2=-1).sum(-1) - (n[:, :, None] * cov * n[:, None, :]).sum((-1, -2))
    return cov, torch.sqrt(torch.clamp(var_tilt, min=0.0)), torch.sqrt(torch.clamp(var_normal, min=0.0))


def _frontal(torch, a, th, ct, st, x0, x1, w, Q, bx, by):
    """estimator._frontal in torch: chi2 of the best frontal pencil (B,)."""
    b = torch.atan2(by, bx)
    gain2 = (Q[:, 2, 2, None] / (bx * bx + by * by)) ** 2
    wv = w / gain2
    e = 2.0 * (b - th)
    phi = 0.5 * torch.atan2((wv * torch.sin(e)).sum(-1), (wv * torch.cos(e)).sum(-1))
    q0, q1, vhat = Q[:, 0, :], Q[:, 1, :], Q[:, 2, :]  # columns of Qt
    sw = torch.sqrt(w)
    zeros = torch.zeros_like(q0)

    def rot(phi):
        c, s = torch.cos(phi)[:, None], torch.sin(phi)[:, None]
        return torch.stack([c * q0 + s * q1, -s * q0 + c * q1, zeros], -1)  # only columns 0, 1 matter

    alpha, J, _ = _model(rot(phi), x0, x1, ct, st)
    r = sw * wrap_line_torch(a - alpha)
    j = sw * (J[0] * vhat[:, 0, None] + J[1] * vhat[:, 1, None] + J[2] * vhat[:, 2, None])
    tiny = torch.finfo(a.dtype).tiny
    phi = phi + (j * r).sum(-1) / torch.clamp((j * j).sum(-1), min=tiny)
    alpha, _, _ = _model(rot(phi), x0, x1, ct, st, jac=False)
    r = sw * wrap_line_torch(a - alpha)
    return (r * r).sum(-1)


def _twin(torch, R, v):
    """Rot(v, pi) R Rot(z, pi) = 2 v (v^T R') - R' with R' = R with columns 0, 1 negated."""
    sign = torch.tensor([-1.0, -1.0, 1.0], dtype=R.dtype, device=R.device)
    Rp = R * sign
    return 2.0 * v[:, :, None] * (v[:, :, None] * Rp).sum(-2, keepdim=True) - Rp


def _fit_chunk(torch, kornia, a, th, ct, st, x, w, m, Cx, oriented, max_iter, tol, low_precision):
    """Everything of estimator.fit_pencil for one chunk of valid-shaped pencils."""
    x0, x1 = x[:, 0:1], x[:, 1:2]
    ca, sa = torch.cos(a), torch.sin(a)
    Q = _virtual_rotation(torch, x[:, 0], x[:, 1])
    bx = Q[:, 0, 0, None] * ca + Q[:, 0, 1, None] * sa
    by = Q[:, 1, 0, None] * ca + Q[:, 1, 1, None] * sa
    R0, bad = _closed_form(torch, bx, by, ct, st, w, Q, oriented, low_precision)
    sw = torch.sqrt(w)
    R, cost, conv, nit, it = _refine(torch, kornia, R0, a, ct, st, x0, x1, sw, max_iter, tol, low_precision)
    v = Q[:, 2, :]
    Rt = _twin(torch, R, v)
    swap = Rt[:, 2, 2] > R[:, 2, 2]
    R, Rt = torch.where(swap[:, None, None], Rt, R), torch.where(swap[:, None, None], R, Rt)
    alpha, J, Jx = _model(R, x0, x1, ct, st)
    res = torch.where(m, wrap_line_torch(a - alpha), torch.zeros((), dtype=a.dtype, device=a.device))
    cov, s_tilt, s_norm = _covariance(torch, R, x0, x1, J, Jx, w, Cx)
    chi2_0 = _frontal(torch, a, th, ct, st, x0, x1, w, Q, bx, by)
    used = m.sum(-1)
    dof = (used - 3).to(a.dtype)
    inflate = torch.where(dof > 0, torch.clamp(cost / torch.clamp(dof, min=1.0), min=1.0), torch.ones_like(dof))
    detectable = (chi2_0 - cost) / inflate > _CHI2_2
    tilt = torch.arccos(torch.clamp((R[:, :, 2] * v).sum(-1), -1.0, 1.0))
    rms = torch.sqrt((w * res * res).sum(-1) / w.sum(-1))
    return {
        "R_cam_from_target": R, "R_twin": Rt, "normal": R[:, :, 2], "normal_twin": Rt[:, :, 2], "ray": v,
        "tilt": tilt, "tilt_sigma": s_tilt, "normal_sigma": s_norm, "cov": cov, "residuals": res,
        "rms": rms, "chi2": cost, "chi2_frontal": chi2_0, "detectable": detectable, "lines_used": used,
        "converged": conv, "iterations_per_pencil": nit, "_bad": bad, "_it": it,
    }


# ----------------------------------------------------------------------------------------
# the whole fit


def _prepare(torch, line_angles, spoke_angles, vertex, sigma, weights, vertex_cov, dev, dt):
    """Broadcast and validate as estimator._as_batch; returns flat tensors + checks."""

    def t(v):
        if isinstance(v, torch.Tensor):
            return v.to(device=dev, dtype=dt)
        return _tensor(torch, v, dt, dev)

    a, th, x = t(line_angles), t(spoke_angles), t(vertex)
    if a.ndim == 0 or x.ndim == 0 or x.shape[-1] != 2 or th.ndim == 0:
        raise InputError("line angles must be (..., N) and the vertex (..., 2)")
    try:  # numpy's: torch.broadcast_shapes imports sympy on first use (0.5 s)
        batch = tuple(np.broadcast_shapes(tuple(a.shape[:-1]), tuple(th.shape[:-1]), tuple(x.shape[:-1])))
        N = np.broadcast_shapes(tuple(a.shape[-1:]), tuple(th.shape[-1:]))[0]
    except ValueError:
        raise InputError(f"shapes do not match: line angles {tuple(a.shape)}, spoke angles "
                         f"{tuple(th.shape)}, vertex {tuple(x.shape)}") from None
    B = math.prod(batch)
    a = a.expand(batch + (N,)).reshape(B, N)
    x = x.expand(batch + (2,)).reshape(B, 2)
    shared = th.ndim == 1 and bool(torch.isfinite(th).all())
    th = th.reshape(1, N) if shared else th.expand(batch + (N,)).reshape(B, N)
    s = t(sigma)
    try:
        s = s.expand(batch + (N,)).reshape(B, N) if s.ndim else s
    except RuntimeError:
        raise InputError(f"sigma of shape {tuple(s.shape)} does not broadcast to {tuple(batch + (N,))}") from None
    if weights is None:
        m = torch.ones((B, N), dtype=torch.bool, device=dev)
    else:
        wt = weights.to(dev) if isinstance(weights, torch.Tensor) else _tensor(torch, weights, torch.float64, dev)
        m = (wt > 0).expand(batch + (N,)).reshape(B, N)
    Cx = None
    if vertex_cov is not None:
        Cx = t(vertex_cov).expand(batch + (2, 2)).reshape(B, 2, 2)
    zero = torch.zeros((), dtype=dt, device=dev)
    # per-pencil checks (numpy raises for the batch; strict=False masks the pencil)
    finite = torch.isfinite(torch.where(m, a + th + s, zero)).all(-1)
    finite &= torch.isfinite(x).all(-1)
    s_full = s if s.ndim else s.expand(B, N)
    pos = ~(m & ~(s_full > 0)).any(-1)
    used = m.sum(-1)
    w = torch.where(m, 1.0 / torch.where(m, s_full, torch.ones((), dtype=dt, device=dev)) ** 2, zero)
    a = torch.where(m, a, zero)
    if not shared:
        th = torch.where(m, th, zero)
    return a, th, x, w, m, Cx, batch, N, B, finite, pos, used


def fit_pencils_torch(line_angles, spoke_angles, vertex, sigma=math.radians(0.1), weights=None, *,
                      vertex_cov=None, device="cpu", dtype="float64", oriented=True, max_iter=30,
                      tol=None, strict=True, output="torch", chunk=None, workers=None):
    """Fit the orientation of many pencils at once (the exact estimator, batched in torch).

    Parameters
    ----------
    line_angles : (B, N) or (..., N) array_like or tensor
        [rad] image angles in normalised coordinates, line k labelled with spoke k;
        oriented (vertex -> tip) when `oriented`, else any of a, a + pi.
    spoke_angles : (B, N) or (N,)
        [rad] theta_k in the target frame (one shared fan is kept unexpanded).
    vertex : (B, 2)
        Normalised image of each vertex.
    sigma : scalar, (N,) or (B, N)
        [rad] standard deviation of each line angle.
    weights : (B, N) or None
        Mask; lines with weight 0 are ignored (missing spokes, may be NaN).
    vertex_cov : (B, 2, 2) or (2, 2) or None
        Covariance of the normalised vertex, carried into the covariance.
    device : "cpu", "cuda", "cuda:k" or torch.device
    dtype : "float64" (default: agrees with numpy) or "float32" (planning maps; the LM
        stops at steps of 1e-5 rad instead of 1e-9)
    oriented, max_iter : as `estimator.fit_pencil`; tol: LM step tolerance [rad].
    strict : bool
        True (default): raise as numpy does when any pencil cannot be fitted (InputError
        for NaN/inf or sigma <= 0, EstimationError for < 3 lines, parallel lines, a vertex
        at infinity). False: fit the others and mark those with ``ok`` False and NaN.
    output : "torch" (tensors on `device`) or "numpy".
    chunk, workers : pencils per chunk (bounds memory; default 16384 on the CPU, 2^18 on
        CUDA) and CPU threads working on chunks (default torch.get_num_threads()). While
        a CPU fit runs, torch's intra-op thread count is set to 1 (restored after).

    Returns
    -------
    dict with the fields of `estimator.PencilFit` (batch shape (...) in front):
    ``R_cam_from_target, R_twin`` (..., 3, 3); ``normal, normal_twin, ray`` (..., 3);
    ``tilt, tilt_sigma, normal_sigma, rms, chi2, chi2_frontal`` (...) [rad / 1];
    ``cov`` (..., 3, 3) [rad^2]; ``residuals`` (..., N) [rad]; ``detectable, converged,
    ambiguous, ok`` (...) bool; ``lines_used, iterations_per_pencil`` (...) int;
    ``iterations`` int (the most LM iterations any pencil took).

    Example
    -------
    >>> import numpy as np
    >>> th = np.radians(np.arange(8) * 20.0)
    >>> a = np.tile(th, (3, 1))                 # three frontal pencils on the optical axis
    >>> fit = fit_pencils_torch(a, th, np.zeros((3, 2)), output="numpy")
    >>> fit["tilt"].round(6).tolist(), fit["detectable"].tolist()
    ([0.0, 0.0, 0.0], [False, False, False])
    """
    torch, kornia = _import_torch()
    dev = resolve_device(device)
    dt = _dtype(torch, dtype)
    low = dt == torch.float32
    if output not in ("torch", "numpy"):
        raise InputError(f"output must be 'torch' or 'numpy', got {output!r}")
    tol = (1e-5 if low else 1e-9) if tol is None else float(tol)
    if workers is None:
        workers = torch.get_num_threads() if dev.type == "cpu" else 1
    with torch.no_grad(), _single_threaded(torch, dev):
        a, th, x, w, m, Cx, batch, N, B, finite, pos, used = _prepare(
            torch, line_angles, spoke_angles, vertex, sigma, weights, vertex_cov, dev, dt)
        far = (x.abs() > _MAX_VERTEX).any(-1)
        ok = finite & pos & (used >= 3) & ~far
        if strict and B and not bool(ok.all()):
            if not bool(finite.all()):
                raise InputError("line angles, spoke angles, sigma and vertex must be finite (NaN or inf given)")
            if not bool(pos.all()):
                raise InputError("sigma must be positive")
            if not bool((used >= 3).all()):
                raise EstimationError(f"a pencil needs at least three lines, got {int(used.min())}")
            raise EstimationError("the vertex is at infinity (the lines are parallel in the image)")
        out = _fit_all(torch, kornia, a, th, x, w, m, Cx, ok, oriented, max_iter, tol, low, dev, chunk, workers)
        if strict and B and bool(out["_bad"].any()):
            raise EstimationError("the lines do not determine a pencil: fewer than three distinct directions")
        ok = ok & ~out.pop("_bad")
        it = out.pop("_it")
        if not bool(ok.all()):
            for k, v in out.items():
                if v.dtype.is_floating_point:
                    out[k] = torch.where(ok.reshape((B,) + (1,) * (v.ndim - 1)), v, torch.nan)
                elif v.dtype == torch.bool and k != "ok":
                    out[k] = v & ok.reshape((B,) + (1,) * (v.ndim - 1))
        out["ok"] = ok
        out["ambiguous"] = ok.clone()
        res = {k: v.reshape(batch + tuple(v.shape[1:])) for k, v in out.items()}
    res["iterations"] = it
    if output == "numpy":
        res = {k: (v.cpu().numpy() if isinstance(v, torch.Tensor) else v) for k, v in res.items()}
    return res


@contextlib.contextmanager
def _single_threaded(torch, dev):
    """torch intra-op threads = 1 on the CPU for the duration (restored after).

    torch's own threads split every op of a chunk across cores, which costs a barrier per
    op and collapses (10-25x slower, measured) as soon as another process holds one of
    the cores; chunks on Python worker threads degrade gracefully instead.
    """
    if dev.type != "cpu":
        yield
        return
    prev = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(prev)


def _fit_all(torch, kornia, a, th, x, w, m, Cx, ok, oriented, max_iter, tol, low, dev, chunk, workers):
    """Run `_fit_chunk` over chunks of the valid pencils, on `workers` threads (CPU)."""
    B, N = a.shape
    shared = th.shape[0] == 1 and B != 1
    idx_ok = torch.nonzero(ok).squeeze(1)
    n_ok = int(idx_ok.numel())
    dt = a.dtype
    nan = float("nan")
    out = {
        "R_cam_from_target": torch.full((B, 3, 3), nan, dtype=dt, device=dev),
        "R_twin": torch.full((B, 3, 3), nan, dtype=dt, device=dev),
        "normal": None, "normal_twin": None,
        "ray": torch.full((B, 3), nan, dtype=dt, device=dev),
        "tilt": torch.full((B,), nan, dtype=dt, device=dev),
        "tilt_sigma": torch.full((B,), nan, dtype=dt, device=dev),
        "normal_sigma": torch.full((B,), nan, dtype=dt, device=dev),
        "cov": torch.full((B, 3, 3), nan, dtype=dt, device=dev),
        "residuals": torch.full((B, N), nan, dtype=dt, device=dev),
        "rms": torch.full((B,), nan, dtype=dt, device=dev),
        "chi2": torch.full((B,), nan, dtype=dt, device=dev),
        "chi2_frontal": torch.full((B,), nan, dtype=dt, device=dev),
        "detectable": torch.zeros(B, dtype=torch.bool, device=dev),
        "lines_used": m.sum(-1),
        "converged": torch.zeros(B, dtype=torch.bool, device=dev),
        "iterations_per_pencil": torch.zeros(B, dtype=torch.int32, device=dev),
        "_bad": torch.zeros(B, dtype=torch.bool, device=dev),
    }
    if chunk is None:
        chunk = _CHUNK_CUDA if dev.type == "cuda" else _CHUNK_CPU
    chunk = max(1, int(chunk))
    all_ok = n_ok == B
    starts = list(range(0, n_ok, chunk))

    def one(s):
        sel = slice(s, s + chunk) if all_ok else idx_ok[s:s + chunk]
        th_c = th if shared else th[sel]
        ct, st = torch.cos(th_c), torch.sin(th_c)
        r = _fit_chunk(torch, kornia, a[sel], th_c, ct, st, x[sel], w[sel], m[sel],
                       None if Cx is None else Cx[sel], oriented, max_iter, tol, low)
        for k, v in r.items():
            if k == "_it" or out.get(k) is None:
                continue
            out[k][sel] = v
        return r["_it"]

    workers = max(1, min(int(workers), len(starts))) if dev.type == "cpu" else 1
    its = [0]
    # On the CPU each chunk runs on one core (see _single_threaded), and `workers` Python
    # threads share the chunks (torch releases the GIL in its kernels); on a GPU the
    # chunks run one after the other, each filling the device.
    if workers == 1:
        its += [one(s) for s in starts]
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            its += list(pool.map(one, starts))
    out["normal"] = out["R_cam_from_target"][:, :, 2]
    out["normal_twin"] = out["R_twin"][:, :, 2]
    out["_it"] = max(its)
    return out


def to_pencil_fit(fit):
    """`estimator.PencilFit` from the dict of `fit_pencils_torch` (tensors or numpy)."""

    def n(v):
        return v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)

    return PencilFit(
        R_cam_from_target=n(fit["R_cam_from_target"]), R_twin=n(fit["R_twin"]), normal=n(fit["normal"]),
        normal_twin=n(fit["normal_twin"]), ray=n(fit["ray"]), tilt=n(fit["tilt"]),
        tilt_sigma=n(fit["tilt_sigma"]), normal_sigma=n(fit["normal_sigma"]), cov=n(fit["cov"]),
        residuals=n(fit["residuals"]), rms=n(fit["rms"]), chi2=n(fit["chi2"]),
        chi2_frontal=n(fit["chi2_frontal"]), detectable=n(fit["detectable"]),
        lines_used=n(fit["lines_used"]), converged=n(fit["converged"]), iterations=int(fit["iterations"]),
        ambiguous=n(fit["ambiguous"]),
    )


# ----------------------------------------------------------------------------------------
# raw pixel segments -> normalised angles (OpenCV lens model, kornia)


def _camera_arrays(camera_or_K, dist):
    from .camera import Camera

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
    >>> from pencilcal.toolkit.camera import Camera
    >>> cam = Camera("opencv", 1920, 1080, [[1500.0, 0, 959.5], [0, 1500.0, 539.5], [0, 0, 1]],
    ...              [-0.3, 0.12, 0.001, -0.002, 0.0])
    >>> xy = undistort_points_torch([[0.0, 0.0], [1919.0, 1079.0]], cam).numpy()
    >>> bool(abs(xy - cam.normalized_from_pixels([[0.0, 0.0], [1919.0, 1079.0]])).max() < 1e-11)
    True
    """
    torch, kornia = _import_torch()
    dev = resolve_device(device)
    dt = _dtype(torch, dtype)
    K, d = _camera_arrays(camera_or_K, dist)
    p = px.to(dev, dt) if isinstance(px, torch.Tensor) else _tensor(torch, px, dt, dev)
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
    torch, _ = _import_torch()
    dt = _dtype(torch, dtype)
    s = segments if isinstance(segments, torch.Tensor) else _tensor(torch, segments, torch.float64, "cpu")
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


# ----------------------------------------------------------------------------------------
# speed


def _random_pencils(n, lines, seed):
    from .frames import rotation_to_z, rotation_about_axis
    from .estimator import pencil_jacobian

    rng = np.random.default_rng(seed)
    off = np.radians(rng.uniform(0, 30, n))
    az = rng.uniform(0, 2 * np.pi, n)
    vertex = np.tan(off)[:, None] * np.stack([np.cos(az), np.sin(az)], -1)
    v = np.concatenate([vertex, np.ones((n, 1))], -1)
    z = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))
    R = (np.swapaxes(rotation_to_z(v), -1, -2) @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi, n))
         @ rotation_about_axis(np.broadcast_to([1.0, 0, 0], (n, 3)), np.radians(rng.uniform(5, 80, n)))
         @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi, n)))
    th = np.radians(np.arange(lines) * (160.0 / max(lines - 1, 1)))
    sigma = np.radians(0.1)
    a = pencil_jacobian(R, vertex, th, with_jacobian=False)[0] + sigma * rng.normal(size=(n, lines))
    return a, th, vertex, sigma


def benchmark_batched(n=200_000, lines=8, device="cpu", dtypes=("float64", "float32"), loop_n=300,
                      numpy_batched_n=50_000, chunk=None, workers=None, seed=0):
    """Fits per second: the torch batched path against the numpy estimator.

    Fits `n` random pencils of `lines` lines (tilt 5-80 deg, vertex up to 30 deg off axis,
    0.1 deg noise) with `fit_pencils_torch` for each dtype in `dtypes`, `loop_n` of them
    one by one with `estimator.fit_pencil` (a Python loop over single pencils) and
    `numpy_batched_n` with one batched `estimator.fit_pencil` call.

    Returns a dict: ``torch_<dtype>_fits_per_s``, ``numpy_loop_fits_per_s``,
    ``numpy_batched_fits_per_s``, ``speedup_<dtype>_vs_loop``, ``<dtype>_pencils_per_minute``,
    ``max_rotation_diff_deg_float32`` (float32 against float64 on the same pencils), the
    sizes, the device and the torch thread count. Nothing is asserted.

    Example
    -------
    >>> r = benchmark_batched(n=2000, loop_n=20, numpy_batched_n=2000)   # doctest: +SKIP
    >>> r["speedup_float64_vs_loop"] > 50                                 # doctest: +SKIP
    True
    """
    torch, _ = _import_torch()
    from .estimator import fit_pencil
    from .frames import rotation_angle

    dev = resolve_device(device)
    a, th, vertex, sigma = _random_pencils(n, lines, seed)
    out = {"n": int(n), "lines": int(lines), "device": str(dev), "torch_threads": torch.get_num_threads(),
           "torch_version": torch.__version__}

    def sync():
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    fits = {}
    for dts in dtypes:
        # warm-up (allocator, kernels), then the timed run on tensors already on the device
        at = torch.as_tensor(a, dtype=getattr(torch, dts), device=dev)
        xt = torch.as_tensor(vertex, dtype=getattr(torch, dts), device=dev)
        tht = torch.as_tensor(th, dtype=getattr(torch, dts), device=dev)
        fit_pencils_torch(at[:4096], tht, xt[:4096], sigma, device=dev, dtype=dts, chunk=chunk, workers=workers)
        sync()
        t0 = time.perf_counter()
        f = fit_pencils_torch(at, tht, xt, sigma, device=dev, dtype=dts, chunk=chunk, workers=workers)
        sync()
        dt_s = time.perf_counter() - t0
        fits[dts] = f
        out[f"torch_{dts}_fits_per_s"] = n / dt_s
        out[f"{dts}_pencils_per_minute"] = 60.0 * n / dt_s
        out[f"torch_{dts}_iterations"] = int(f["iterations"])
    t0 = time.perf_counter()
    for i in range(loop_n):
        fit_pencil(a[i], th, vertex[i], sigma=sigma)
    out["numpy_loop_fits_per_s"] = loop_n / (time.perf_counter() - t0)
    nb = min(numpy_batched_n, n)
    t0 = time.perf_counter()
    ref = fit_pencil(a[:nb], th, vertex[:nb], sigma=sigma)
    out["numpy_batched_fits_per_s"] = nb / (time.perf_counter() - t0)
    for dts in dtypes:
        out[f"speedup_{dts}_vs_loop"] = out[f"torch_{dts}_fits_per_s"] / out["numpy_loop_fits_per_s"]
        out[f"speedup_{dts}_vs_numpy_batched"] = out[f"torch_{dts}_fits_per_s"] / out["numpy_batched_fits_per_s"]
        R = fits[dts]["R_cam_from_target"][:nb].double().cpu().numpy()
        out[f"max_rotation_diff_deg_{dts}_vs_numpy"] = float(np.degrees(rotation_angle(R, ref.R_cam_from_target)).max())
    return out


if __name__ == "__main__":  # python -m pencilcal.toolkit.torch_estimator [n] [cpu|cuda]
    import json
    import sys

    args = sys.argv[1:]
    res = benchmark_batched(n=int(float(args[0])) if args else 200_000, device=args[1] if len(args) > 1 else "cpu")
    print(json.dumps(res, indent=1))
