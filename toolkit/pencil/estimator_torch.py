"""The exact estimator in torch: batched fits of millions of pencils, on the CPU or a GPU.

`fit_pencils_torch` is `estimator.fit_pencil` written for torch, so that Monte Carlo maps
(validation/sensitivity.py), sequences of many frames and planning studies run at
hundreds of thousands of fits per second. It follows the numpy estimator step by step
and agrees with it to 1e-6 deg in float64 (median 1e-13 deg; the largest differences are
where numpy's LM stops on its relative-cost test; tests/toolkit/pencil/test_torch_estimator.py):

1. Closed-form start in the virtual camera that looks along the vertex ray: a batched
   DLT of the 2x2 matrix A in ``(cos b_k, sin b_k) ~ A (cos theta_k, sin theta_k)``
   (null vector of the 4x4 normal matrix by inverse iteration), the analytic signed 2x2
   SVD, and cos(gamma) = s2 / s1 (docs/method.md, "The exact estimator").
2. Levenberg-Marquardt on wrapped, weighted line residuals (period pi), with left
   perturbations ``R <- expm([delta]x) R`` (Rodrigues), per-pencil damping and masks;
   converged pencils leave the working set, so stragglers do not make everybody iterate.
3. Covariance (J^T W J)^-1 with the vertex covariance carried in, tilt and normal sigma.
4. Frontal likelihood-ratio test (chi-square, 2 dof, level `defaults.DETECTION_LEVEL`)
   for ``detectable``; the twin ``R' = Rot(v_d, pi) R Rot(z, pi)``, ordered as numpy
   does (the normal closer to the optical axis first).

torch and kornia are optional (``pip install torch==2.13.0 && pip install -e ".[torch]"``);
they are imported only when a function here runs. Without them every entry point raises
`torch_backend.TorchUnavailableError` (an `InputError` and an `ImportError`) whose one-line
message says how to install them. `torch_backend.torch_available()` tells without raising.

Three things differ from numpy on purpose:

- ``converged`` is judged when a pencil leaves the LM. The numpy loop keeps multiplying the
  damping of pencils that stopped early while others iterate, so in large batches with a
  slow straggler it can report converged=False for pencils that did converge.
- ``strict=False`` fits what can be fitted and marks the rest (``ok`` False, NaN fields)
  instead of raising for the whole batch.
- Lines that do not determine a pencil (fewer than three distinct directions) are
  caught when the second-smallest eigenvalue of the DLT matrix is below 1e-12 of its
  trace (numpy: of its largest eigenvalue; the two differ by at most 4x, far from any
  pencil that is nearly degenerate without being so).
- The last LM step, once below `tol`, is taken without evaluating the model after it
  (numpy evaluates it and stops); the result moves by less than `tol`.

Speed comes from the layout, not from cleverness in the algebra: per-line tensors are
lines-major (N, B), per-pencil 3x3 and 4x4 algebra is written out on (B,) tensors, and
nothing in the loop calls a batched small matmul, ``torch.linalg.eigh`` or a general
rotation conversion (kornia's, tried first, cost as much per call as a whole model
evaluation; measured in docs/performance.md). kornia does the lens undistortion.

Angles are radians, image angles in normalised camera coordinates (z = 1 plane, after
undistortion); `points_torch.segment_angles_torch` turns raw pixel segments of OpenCV-model
cameras into such angles in batches (kornia's undistortion, polished by Newton steps). The
speed against the numpy estimator is measured by `pencilcal bench` (validation/bench.py,
`benchmark_batched`).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec, rotation_angle
>>> from pencilcal.toolkit.pencil.spec import image_angles
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

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.defaults import CHI2_2_DETECTION, MAX_VERTEX, MIN_COS
from pencilcal.toolkit.pencil.estimator import PencilFit
from pencilcal.toolkit.pencil.torch_backend import as_tensor, import_torch, resolve_device, torch_dtype

__all__ = ["wrap_line_torch", "fit_pencils_torch", "to_pencil_fit"]

# pencils per chunk: 16384 x 8 lines keeps the temporaries (1 MB each) near the cache,
# and each chunk runs on one core (_single_threaded); chunks run on `workers` threads
_CHUNK_CPU = 16384
_CHUNK_CUDA = 1 << 18


def wrap_line_torch(angle):
    """`angles.wrap_line` for tensors: line angles (period pi) into (-pi/2, pi/2].

    The same rule, written with torch.remainder (sign of the divisor, as np.remainder), so
    it runs on the tensor's device; tests check it against `angles.wrap_line`.
    """
    import torch

    h = math.pi / 2.0
    return h - torch.remainder(h - angle, math.pi)


# ----------------------------------------------------------------------------------------
# the fit of one chunk, lines-major
#
# Per-line tensors are (N, B) ("lines-major"): the per-pencil sums of the normal equations
# run over the leading dimension, which torch does as contiguous vector adds (sums over a
# short last dimension cost twice as much). Per-pencil quantities are (B,) tensors and
# small matrices are written out entry by entry: batched 3x3 and 4x4 matmuls, torch.where
# on (N, B) and torch.linalg.eigh on 4x4 cost 10-50x the arithmetic they do (measured,
# torch 2.13 CPU). The LM keeps only the first two columns of R (the model needs no more);
# the third is their cross product at the end.


def _cross(a, b):
    """a x b for 3-tuples of tensors."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _virtual_rows(torch, x0, x1):
    """Rows of Q (3-tuples of (B,)) with Q (x, y, 1) ~ (0, 0, 1): estimator._virtual_rotation."""
    n = torch.sqrt(1.0 + x0 * x0 + x1 * x1)
    vx, vy, c = x0 / n, x1 / n, 1.0 / n
    kx, ky = vy, -vx
    f = 1.0 / (1.0 + c)
    fxy = f * kx * ky
    return ((1.0 - f * ky * ky, fxy, ky), (fxy, 1.0 - f * kx * kx, -kx), (-ky, kx, c))


def _directions(torch, c0, c1, ct, st):
    """Spoke directions R (cos t, sin t, 0) in the camera: 3-tuple of (N, B)."""
    return tuple(torch.addcmul(ct * c0[i], st, c1[i]) for i in range(3))


def _angles(torch, d, x0, x1):
    """Image vectors (wx, wy) of the lines through the vertex, and their angles alpha."""
    wx = torch.addcmul(d[0], d[2], x0, value=-1.0)
    wy = torch.addcmul(d[1], d[2], x1, value=-1.0)
    return wx, wy, torch.atan2(wy, wx)


def _line_residual(torch, a, alpha):
    """a - alpha wrapped to [-pi/2, pi/2] by rounding (the LM's own; ties at exactly pi/2 are
    immaterial there, and torch.remainder costs 10x). Outputs use wrap_line_torch."""
    d = a - alpha
    return torch.sub(d, torch.round(d * (1.0 / math.pi)), alpha=math.pi)


def _rot_jacobian(torch, d, wx, wy, x0, x1):
    """d alpha / d delta for left perturbations R <- expm([delta]x) R, as p * (K0, K1, K2)
    with p = 1 / |w|^2 (the factor is kept apart: the normal equations need p^2 only)."""
    p = torch.reciprocal(torch.addcmul(wx * wx, wy, wy))
    e = torch.addcmul(wy * x0, wx, x1, value=-1.0)
    K0 = torch.addcmul(d[1] * e, d[2], wx, value=-1.0)
    K1 = torch.addcmul(d[2] * wy, d[0], e).neg_()
    K2 = torch.addcmul(d[0] * wx, d[1], wy)
    return p, (K0, K1, K2)


def _normal_equations(torch, p, K, w, res):
    """H = sum w J J^T (6 entries h00 h01 h02 h11 h12 h22) and g = sum w J res, (B,) each."""
    q = w * p * p
    qK = [q * k for k in K]
    H = ((qK[0] * K[0]).sum(0), (qK[0] * K[1]).sum(0), (qK[0] * K[2]).sum(0),
         (qK[1] * K[1]).sum(0), (qK[1] * K[2]).sum(0), (qK[2] * K[2]).sum(0))
    wpr = w * p * res
    g = tuple((wpr * k).sum(0) for k in K)
    return H, g


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


def _rotate(torch, s, c):
    """expm([s]x) c for a rotation vector s and a vector c (3-tuples of (B,)), by Rodrigues
    with sin(t)/t and (1 - cos t)/t^2 from torch.sinc (exact at t = 0)."""
    t = torch.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
    A = torch.sinc(t * (1.0 / math.pi))
    h = torch.sinc(t * (0.5 / math.pi))
    Bc = 0.5 * h * h
    u = _cross(s, c)
    v = _cross(s, u)
    return tuple(c[i] + A * u[i] + Bc * v[i] for i in range(3))


def _ldl_factor(A, n):
    """LDL^T of symmetric n x n matrices given as A[i][j] ((B,) tensors, i >= j used):
    returns (L, 1/D) with L[(i, j)] for i > j."""
    L, Dinv, D = {}, [], []
    for j in range(n):
        dj = A[j][j] - sum(L[(j, k)] * L[(j, k)] * D[k] for k in range(j))
        D.append(dj)
        Dinv.append(1.0 / dj)
        for i in range(j + 1, n):
            L[(i, j)] = (A[i][j] - sum(L[(i, k)] * L[(j, k)] * D[k] for k in range(j))) * Dinv[j]
    return L, Dinv


def _ldl_solve(L, Dinv, b):
    n = len(b)
    y = []
    for i in range(n):
        y.append(b[i] - sum(L[(i, k)] * y[k] for k in range(i)))
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = y[i] * Dinv[i] - sum(L[(k, i)] * x[k] for k in range(i + 1, n))
    return x


def _normalised(torch, x):
    return [xi * torch.rsqrt(sum(xj * xj for xj in x)) for xi in x]


def _smallest_eigenpair4(torch, M, iterations=4):
    """The eigenvector of the smallest eigenvalue of symmetric positive semi-definite 4x4
    matrices, and a test for a two-dimensional null space, by inverse iteration, written out.

    M: 4 x 4 nested lists of (B,) tensors. Returns (h: 4 (B,) tensors, unit; lam2_bound (B,),
    an upper bound of the second-smallest eigenvalue that is tight when that eigenvalue
    is small; scale (B,), the trace of M).

    Inverse iteration on M + delta I (delta = 1000 eps trace keeps the factorisation finite on
    singular M without moving eigenvectors) converges by (l1 + delta) / (l2 + delta) per
    step: ~1e-6 for a noisy pencil, ~1e-12 for an exact one (float64); the LM after it does not need
    more. Deflating h (M + trace h h^T) and iterating again gives l2 the same way. Batched
    torch.linalg.eigh of 4x4 costs 20x this (torch 2.13, CPU).
    """
    trace = M[0][0] + M[1][1] + M[2][2] + M[3][3]
    tiny = torch.finfo(trace.dtype).tiny
    scale = trace.clamp(min=tiny)
    delta = 1e3 * torch.finfo(trace.dtype).eps * scale
    Ms = [[M[i][j] + delta if i == j else M[i][j] for j in range(4)] for i in range(4)]
    L, Dinv = _ldl_factor(Ms, 4)
    one = torch.ones_like(trace)
    # start from a fixed generic direction (no exact zero component along any axis)
    x = _normalised(torch, [one, 0.7 * one, -0.5 * one, 0.3 * one])
    for _ in range(iterations):
        x = _normalised(torch, _ldl_solve(L, Dinv, x))
    h = x
    Md = [[Ms[i][j] + scale * h[i] * h[j] for j in range(4)] for i in range(4)]
    L, Dinv = _ldl_factor(Md, 4)
    y = _normalised(torch, [0.3 * one, -0.5 * one, 0.7 * one, one])
    for _ in range(2):
        y = _normalised(torch, _ldl_solve(L, Dinv, y))
    My = [sum(M[i][j] * y[j] for j in range(4)) for i in range(4)]
    lam2 = sum(y[i] * My[i] for i in range(4))
    return h, lam2, scale


def _closed_form(torch, cb, sb, ct, st, w, Qr, oriented, low_precision):
    """DLT of A in (cos b, sin b) ~ A (cos theta, sin theta), its signed SVD (as
    estimator._closed_form); returns (columns 0, 1 of R0 as 3-tuples of (B,), bad (B,))."""
    u, v, z = w * sb * sb, -(w * sb * cb), w * cb * cb
    c2, cs, s2 = ct * ct, ct * st, st * st
    m00, m01, m11 = (u * c2).sum(0), (u * cs).sum(0), (u * s2).sum(0)
    m02, m03, m13 = (v * c2).sum(0), (v * cs).sum(0), (v * s2).sum(0)
    m22, m23, m33 = (z * c2).sum(0), (z * cs).sum(0), (z * s2).sum(0)
    M = [[m00, m01, m02, m03], [m01, m11, m03, m13], [m02, m03, m22, m23], [m03, m13, m23, m33]]
    (a, b, c, d), lam2, trace = _smallest_eigenpair4(torch, M)
    # a unique pencil needs a one-dimensional null space. Rounding leaves the second
    # eigenvalue of a degenerate M at ~1e-16 (float32: ~1e-7) of the largest
    bad = lam2 <= (1e-6 if low_precision else 1e-12) * trace
    if oriented:
        agree = (w * (torch.addcmul(a * ct, b, st) * cb + torch.addcmul(c * ct, d, st) * sb)).sum(0)
        sgn = torch.where(agree < 0, -1.0, 1.0).to(a.dtype)
        a, b, c, d = a * sgn, b * sgn, c * sgn, d * sgn
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    q, r = torch.hypot(E, H), torch.hypot(F, G)
    a1, a2 = torch.atan2(G, F), torch.atan2(H, E)
    theta0, phi = (a2 - a1) / 2, (a2 + a1) / 2
    tiny = torch.finfo(q.dtype).tiny
    cos_g = torch.clamp((q - r) / torch.clamp(q + r, min=tiny), min=float(MIN_COS), max=1.0)
    sin_g = torch.sqrt(1.0 - cos_g * cos_g)
    # Rz(phi) Rx(gamma) Rz(theta0), columns 0 and 1, then R0 = Q^T of that
    cp, sp, c0, s0 = torch.cos(phi), torch.sin(phi), torch.cos(theta0), torch.sin(theta0)
    Z0 = (cp * c0 - sp * cos_g * s0, sp * c0 + cp * cos_g * s0, sin_g * s0)
    Z1 = (-cp * s0 - sp * cos_g * c0, -sp * s0 + cp * cos_g * c0, sin_g * c0)

    def qt(Z):
        return tuple(Qr[0][i] * Z[0] + Qr[1][i] * Z[1] + Qr[2][i] * Z[2] for i in range(3))

    return qt(Z0), qt(Z1), bad


def _refine(torch, col0, col1, a, ct, st, x0, x1, w, max_iter, tol, low_precision):
    """LM of estimator.refine_pencil on one chunk (lines-major).

    Returns (col0, col1, cost, converged, nit, it). Two things save model evaluations
    without moving the result by more than `tol`:

    - a step below `tol` is the last one and is taken without evaluating the model there
      (numpy evaluates it, keeps it unless rounding says the cost rose, and stops);
    - the pencils that stop leave the working set as soon as a fifth of it has stopped,
      so stragglers do not make everybody iterate.
    """
    B = x0.shape[0]
    dev, dt = x0.device, x0.dtype
    rel = 1e-5 if low_precision else 1e-14
    tiny = torch.finfo(dt).tiny
    per_pencil_spokes = ct.shape[1] == B and B > 1

    def evaluate(c0, c1, a, ct, st, x0, x1, w):
        d = _directions(torch, c0, c1, ct, st)
        wx, wy, alpha = _angles(torch, d, x0, x1)
        res = _line_residual(torch, a, alpha)
        p, K = _rot_jacobian(torch, d, wx, wy, x0, x1)
        H, g = _normal_equations(torch, p, K, w, res)
        return (w * res * res).sum(0), H, g

    cost, H, g = evaluate(col0, col1, a, ct, st, x0, x1, w)
    lam = torch.full((B,), 1e-4, dtype=dt, device=dev)
    active = torch.ones(B, dtype=torch.bool, device=dev)
    nit = torch.zeros(B, dtype=torch.int32, device=dev)
    # full-chunk state, written back when the working set shrinks
    out = {"c0": list(col0), "c1": list(col1), "cost": cost, "lam": lam, "nit": nit}
    idx = None  # None: the working set is the whole chunk
    n_set = B
    it = 0

    def write_back():
        # in place into the tensors the chunk started with (nothing else holds them)
        sel = slice(None) if idx is None else idx
        for i in range(3):
            out["c0"][i][sel] = col0[i]
            out["c1"][i][sel] = col1[i]
        out["cost"][sel], out["lam"][sel], out["nit"][sel] = cost, lam, nit

    for it in range(1, max_iter + 1):
        nit = nit + active.to(torch.int32)
        h00, h01, h02, h11, h12, h22 = H
        floor = 1e-12 * (h00 + h11 + h22) + tiny
        lf = lam * floor
        s = _sym3_solve(h00 * (1.0 + lam) + lf, h01, h02, h11 * (1.0 + lam) + lf, h12,
                        h22 * (1.0 + lam) + lf, *g)
        s = tuple(si * active for si in s)
        n0, n1 = _rotate(torch, s, col0), _rotate(torch, s, col1)
        last = active & ((s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) < tol * tol)
        col0 = tuple(torch.where(last, ni, ci) for ni, ci in zip(n0, col0))
        col1 = tuple(torch.where(last, ni, ci) for ni, ci in zip(n1, col1))
        active = active & ~last
        n_active = int(active.sum())
        if n_active == 0:
            break
        if n_active <= 0.8 * n_set and n_set > 64:
            write_back()
            sel = torch.nonzero(active).squeeze(1)
            idx = sel if idx is None else idx[sel]
            col0, col1 = tuple(c[sel] for c in col0), tuple(c[sel] for c in col1)
            n0, n1 = tuple(c[sel] for c in n0), tuple(c[sel] for c in n1)
            H, g = tuple(h[sel] for h in H), tuple(gi[sel] for gi in g)
            cost, lam, nit, active = cost[sel], lam[sel], nit[sel], active[sel]
            a, w, x0, x1 = a[:, sel], w[:, sel], x0[sel], x1[sel]
            if per_pencil_spokes:
                ct, st = ct[:, sel], st[:, sel]
            n_set = n_active
        cost_n, H_n, g_n = evaluate(n0, n1, a, ct, st, x0, x1, w)
        better = (cost_n <= cost) & active
        col0 = tuple(torch.where(better, ni, ci) for ni, ci in zip(n0, col0))
        col1 = tuple(torch.where(better, ni, ci) for ni, ci in zip(n1, col1))
        H = tuple(torch.where(better, hn, h) for hn, h in zip(H_n, H))
        g = tuple(torch.where(better, gn, gi) for gn, gi in zip(g_n, g))
        stalled = better & ((cost - cost_n) <= rel * cost)
        if low_precision:
            # float32 rounding: a cost that neither falls nor rises has converged too
            stalled = stalled | (~better & ((cost_n - cost).abs() <= rel * cost))
        cost = torch.where(better, cost_n, cost)
        lam = torch.where(active, lam * torch.where(better, 0.1, 10.0).to(dt), lam)
        active = active & ~(stalled | (lam > 1e10))
    write_back()
    return tuple(out["c0"]), tuple(out["c1"]), out["cost"], out["lam"] <= 1e10, out["nit"], it


def _covariance(torch, n, v, nv, p, K, Kx, w, Cx):
    """estimator._covariance in torch, the 3x3 algebra written out. n: column 2 of R;
    v: unit vertex ray, nv = |(x, y, 1)|; p, K: `_rot_jacobian`; Kx: d alpha / d x over p."""
    H, _ = _normal_equations(torch, p, K, w, torch.zeros((), dtype=p.dtype, device=p.device))
    h00, h01, h02, h11, h12, h22 = H
    ridge = 1e-14 * (h00 + h11 + h22)
    a, b, c, d, e, f = h00 + ridge, h01, h02, h11 + ridge, h12, h22 + ridge
    A00, A01, A02 = d * f - e * e, c * e - b * f, b * e - c * d
    A11, A12, A22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A00 + b * A01 + c * A02
    Hinv = torch.stack([torch.stack([A00, A01, A02], -1), torch.stack([A01, A11, A12], -1),
                        torch.stack([A02, A12, A22], -1)], -2) / det[:, None, None]
    nxv = _cross(n, v)
    sin_raw = torch.sqrt(nxv[0] * nxv[0] + nxv[1] * nxv[1] + nxv[2] * nxv[2])
    sin_g = torch.clamp(sin_raw, min=1e-12)
    g_rot = -torch.stack(nxv, -1) / sin_g[:, None]
    var_tilt = (g_rot[:, :, None] * Hinv * g_rot[:, None, :]).sum((-1, -2))
    # at exactly zero tilt the angles do not see the tilt to first order: the bound is
    # infinite, not the zero the gradient gives (as numpy)
    var_tilt = torch.where(sin_raw < 1e-9, torch.inf, var_tilt)
    cov = Hinv
    nn = torch.stack(n, -1)
    if Cx is not None:
        q = w * p * p
        Kw = torch.stack([torch.stack([(q * k * kx).sum(0) for kx in Kx], -1) for k in K], -2)  # (B, 3, 2)
        G = -Hinv @ Kw
        cov = cov + G @ Cx @ G.transpose(-1, -2)
        vv = torch.stack(v, -1)
        eye = torch.eye(3, dtype=p.dtype, device=p.device)
        P = (eye - vv[:, :, None] * vv[:, None, :])[:, :, :2] / nv[:, None, None]
        g_x = (g_rot[:, None, :] @ G)[:, 0] - (nn[:, None, :] @ P)[:, 0] / sin_g[:, None]
        var_tilt = var_tilt + (g_x[:, None, :] @ Cx @ g_x[:, :, None])[:, 0, 0]
    # trace((I - n n^T) cov (I - n n^T)) = trace(cov) - n^T cov n
    var_normal = torch.diagonal(cov, dim1=-2, dim2=-1).sum(-1) - (nn[:, :, None] * cov * nn[:, None, :]).sum((-1, -2))
    return cov, torch.sqrt(torch.clamp(var_tilt, min=0.0)), torch.sqrt(torch.clamp(var_normal, min=0.0))


def _frontal(torch, a, cb, sb, nb2, ct, st, x0, x1, w, Qr):
    """estimator._frontal in torch: chi2 of the best frontal pencil (B,).

    cos/sin of 2 (b - theta) come from the unit virtual line directions (cb, sb) by the
    double-angle formulas instead of atan2/sin/cos (the same numbers to rounding).
    """
    gain2 = (Qr[2][2] / nb2) ** 2
    wv = w / gain2
    cd = torch.addcmul(cb * ct, sb, st)   # cos(b - theta)
    sd = torch.addcmul(sb * ct, cb, st, value=-1.0)   # sin(b - theta)
    S = (wv * cd * sd).sum(0) * 2.0
    C = (wv * torch.addcmul(cd * cd, sd, sd, value=-1.0)).sum(0)
    phi = 0.5 * torch.atan2(S, C)
    q0, q1, vhat = Qr[0], Qr[1], Qr[2]  # rows of Q: columns of Q^T

    def rot(phi):
        c, s = torch.cos(phi), torch.sin(phi)
        return (tuple(c * q0[i] + s * q1[i] for i in range(3)), tuple(-s * q0[i] + c * q1[i] for i in range(3)))

    c0, c1 = rot(phi)
    d = _directions(torch, c0, c1, ct, st)
    wx, wy, alpha = _angles(torch, d, x0, x1)
    res = _line_residual(torch, a, alpha)
    p, K = _rot_jacobian(torch, d, wx, wy, x0, x1)
    # rotating about the ray is the left perturbation delta = phi * v_hat: one GN step
    j = p * (K[0] * vhat[0] + K[1] * vhat[1] + K[2] * vhat[2])
    wj = w * j
    tiny = torch.finfo(a.dtype).tiny
    phi = phi + (wj * res).sum(0) / torch.clamp((wj * j).sum(0), min=tiny)
    c0, c1 = rot(phi)
    _, _, alpha = _angles(torch, _directions(torch, c0, c1, ct, st), x0, x1)
    res = _line_residual(torch, a, alpha)
    return (w * res * res).sum(0)


def _fit_chunk(torch, a, th, ct, st, x, w, m, Cx, oriented, max_iter, tol, low_precision):
    """Everything of estimator.fit_pencil for one chunk of valid-shaped pencils.

    a, w, m: (B, N); th, ct, st: (1, N) or (B, N); x: (B, 2); Cx: (B, 2, 2) or None.
    """
    aT, wT = a.t().contiguous(), w.t().contiguous()
    ctT, stT = ct.t().contiguous(), st.t().contiguous()
    x0, x1 = x[:, 0].contiguous(), x[:, 1].contiguous()
    Qr = _virtual_rows(torch, x0, x1)
    ca, sa = torch.cos(aT), torch.sin(aT)
    bx = torch.addcmul(Qr[0][0] * ca, Qr[0][1], sa)
    by = torch.addcmul(Qr[1][0] * ca, Qr[1][1], sa)
    nb2 = torch.addcmul(bx * bx, by, by)
    inb = torch.rsqrt(nb2)
    cb, sb = bx * inb, by * inb
    col0, col1, bad = _closed_form(torch, cb, sb, ctT, stT, wT, Qr, oriented, low_precision)
    col0, col1, cost, conv, nit, it = _refine(torch, col0, col1, aT, ctT, stT, x0, x1, wT, max_iter, tol, low_precision)
    col2 = _cross(col0, col1)
    v = Qr[2]
    # the twin Rot(v, pi) R Rot(z, pi): columns 0, 1 -> c - 2 v (v.c), column 2 -> 2 v (v.c) - c
    def reflect(c, sign):
        k = 2.0 * (v[0] * c[0] + v[1] * c[1] + v[2] * c[2])
        return tuple(sign * (k * v[i] - c[i]) for i in range(3))

    t0, t1, t2 = reflect(col0, -1.0), reflect(col1, -1.0), reflect(col2, 1.0)
    swap = t2[2] > col2[2]

    def pick(x, y):
        return tuple(torch.where(swap, yi, xi) for xi, yi in zip(x, y))

    R_cols = (pick(col0, t0), pick(col1, t1), pick(col2, t2))
    T_cols = (pick(t0, col0), pick(t1, col1), pick(t2, col2))
    d = _directions(torch, R_cols[0], R_cols[1], ctT, stT)
    wx, wy, alpha = _angles(torch, d, x0, x1)
    mT = m.t()
    res = torch.where(mT, wrap_line_torch(aT - alpha), torch.zeros((), dtype=a.dtype, device=a.device))
    p, K = _rot_jacobian(torch, d, wx, wy, x0, x1)
    Kx = (d[2] * wy, -(d[2] * wx)) if Cx is not None else None
    nv = torch.sqrt(1.0 + x0 * x0 + x1 * x1)
    cov, s_tilt, s_norm = _covariance(torch, R_cols[2], v, nv, p, K, Kx, wT, Cx)
    chi2_0 = _frontal(torch, aT, cb, sb, nb2, ctT, stT, x0, x1, wT, Qr)
    used = m.sum(-1)
    dof = (used - 3).to(a.dtype)
    inflate = torch.where(dof > 0, torch.clamp(cost / torch.clamp(dof, min=1.0), min=1.0), torch.ones_like(dof))
    detectable = (chi2_0 - cost) / inflate > CHI2_2_DETECTION
    n = R_cols[2]
    tilt = torch.arccos(torch.clamp(n[0] * v[0] + n[1] * v[1] + n[2] * v[2], -1.0, 1.0))
    rms = torch.sqrt((wT * res * res).sum(0) / wT.sum(0))

    def mat(cols):
        return torch.stack([torch.stack(c, -1) for c in cols], -1)

    R, Rt = mat(R_cols), mat(T_cols)
    return {
        "R_cam_from_target": R, "R_twin": Rt, "normal": R[:, :, 2], "normal_twin": Rt[:, :, 2],
        "ray": torch.stack(v, -1), "tilt": tilt, "tilt_sigma": s_tilt, "normal_sigma": s_norm, "cov": cov,
        "residuals": res.t(), "rms": rms, "chi2": cost, "chi2_frontal": chi2_0, "detectable": detectable,
        "lines_used": used, "converged": conv, "iterations_per_pencil": nit, "_bad": bad, "_it": it,
    }


# ----------------------------------------------------------------------------------------
# the whole fit


def _prepare(torch, line_angles, spoke_angles, vertex, sigma, weights, vertex_cov, dev, dt):
    """Broadcast and validate as estimator._as_batch; returns flat tensors + checks."""

    def t(v):
        if isinstance(v, torch.Tensor):
            return v.to(device=dev, dtype=dt)
        return as_tensor(torch, v, dt, dev)

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
        wt = weights.to(dev) if isinstance(weights, torch.Tensor) else as_tensor(torch, weights, torch.float64, dev)
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
    torch, _ = import_torch()  # kornia too: the [torch] extra is one install
    dev = resolve_device(device)
    dt = torch_dtype(torch, dtype)
    low = dt == torch.float32
    if output not in ("torch", "numpy"):
        raise InputError(f"output must be 'torch' or 'numpy', got {output!r}")
    tol = (1e-5 if low else 1e-9) if tol is None else float(tol)
    if workers is None:
        workers = torch.get_num_threads() if dev.type == "cpu" else 1
    with torch.no_grad(), _single_threaded(torch, dev):
        a, th, x, w, m, Cx, batch, N, B, finite, pos, used = _prepare(
            torch, line_angles, spoke_angles, vertex, sigma, weights, vertex_cov, dev, dt)
        far = (x.abs() > MAX_VERTEX).any(-1)
        ok = finite & pos & (used >= 3) & ~far
        if strict and B and not bool(ok.all()):
            if not bool(finite.all()):
                raise InputError("line angles, spoke angles, sigma and vertex must be finite (NaN or inf given)")
            if not bool(pos.all()):
                raise InputError("sigma must be positive")
            if not bool((used >= 3).all()):
                raise EstimationError(f"a pencil needs at least three lines, got {int(used.min())}")
            raise EstimationError("the vertex is at infinity (the lines are parallel in the image)")
        out = _fit_all(torch, a, th, x, w, m, Cx, ok, oriented, max_iter, tol, low, dev, chunk, workers)
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


def _fit_all(torch, a, th, x, w, m, Cx, ok, oriented, max_iter, tol, low, dev, chunk, workers):
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
        r = _fit_chunk(torch, a[sel], th_c, ct, st, x[sel], w[sel], m[sel],
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
