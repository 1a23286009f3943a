"""The exact estimator for ONE pencil in plain Python floats (private to estimator.py).

numpy costs a few microseconds per call whatever the array size, and a single pencil's fit
makes hundreds of tiny calls; the same arithmetic on Python floats is several times faster
for the few lines of one pencil. Every step mirrors the batched functions of estimator.py
(closed form, Levenberg-Marquardt with the same damping and stopping rules, twin order,
covariance, frontal fit); tests/toolkit/pencil/test_estimator.py holds the two equal.
`fit_one` runs the steps in order: `_virtual_rotation`, `_closed_form`, `_refine`,
`_twins_in_order`, `_covariance`, `_frontal`.

Example
-------
>>> from pencilcal.toolkit.pencil.defaults import CHI2_2_DETECTION, MIN_COS
>>> th = [0.0, 0.5, 1.0, 1.5]                  # a frontal pencil on the optical axis
>>> out = fit_one(th, th, (0.0, 0.0), [1e-3] * 4, True, 30, 1e-9, None, MIN_COS, CHI2_2_DETECTION)
>>> bool(out["tilt"] < 1e-6), bool(out["detectable"]), int(out["lines_used"])
(True, False, 4)
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.pencil.sequence_noise import inflation

_HALF_PI = 0.5 * math.pi


def _wrap_line(x):
    """angles.wrap_line on a float [rad]: pi/2 - ((pi/2 - x) mod pi), floored modulo like np.remainder."""
    return _HALF_PI - ((_HALF_PI - x) % math.pi)


def _matmul(A, B):
    """A B for 3x3 matrices as nested tuples."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = B
    return ((a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21, a00 * b02 + a01 * b12 + a02 * b22),
            (a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21, a10 * b02 + a11 * b12 + a12 * b22),
            (a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21, a20 * b02 + a21 * b12 + a22 * b22))


def _transpose(A):
    """A^T for a 3x3 matrix as nested tuples."""
    return tuple(tuple(A[j][i] for j in range(3)) for i in range(3))


def _rotvec(r0, r1, r2):
    """expm([r]x) (3x3 tuples) of the rotation vector (r0, r1, r2) [rad], by Rodrigues."""
    t = max(math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-150)
    a = math.sin(t) / t
    h = math.sin(0.5 * t)
    b = 2.0 * h * h / (t * t)
    bx, by, bz = b * r0, b * r1, b * r2
    return ((1.0 - by * r1 - bz * r2, bx * r1 - a * r2, bx * r2 + a * r1),
            (bx * r1 + a * r2, 1.0 - bx * r0 - bz * r2, by * r2 - a * r0),
            (bx * r2 - a * r1, by * r2 + a * r0, 1.0 - bx * r0 - by * r1))


def _solve3(H, g):
    """H (3x3, symmetric positive definite) x = g by Cramer's rule."""
    a, b, c = H[0]
    _, e, f = H[1]
    i = H[2][2]
    A = e * i - f * f
    B = c * f - b * i
    C = b * f - c * e
    det = a * A + b * B + c * C
    E = a * i - c * c
    F = b * c - a * f
    I_ = a * e - b * b
    inv = ((A, B, C), (B, E, F), (C, F, I_))
    return tuple((inv[k][0] * g[0] + inv[k][1] * g[1] + inv[k][2] * g[2]) / det for k in range(3)), inv, det


def _model(R, x0, x1, ct, st, jac=True):
    """Image angles of the spokes and their Jacobians (estimator._model for one pencil)."""
    out_a, out_J, out_Jx = [], [], []
    r00, r01 = R[0][0], R[0][1]
    r10, r11 = R[1][0], R[1][1]
    r20, r21 = R[2][0], R[2][1]
    for c, s in zip(ct, st):
        dx = r00 * c + r01 * s
        dy = r10 * c + r11 * s
        dz = r20 * c + r21 * s
        wx = dx - x0 * dz
        wy = dy - x1 * dz
        out_a.append(math.atan2(wy, wx))
        if jac:
            inv = 1.0 / (wx * wx + wy * wy)
            gx, gy = -wy * inv, wx * inv
            u2 = -(gx * x0 + gy * x1)
            out_J.append((dy * u2 - dz * gy, dz * gx - dx * u2, dx * gy - dy * gx))
            out_Jx.append((-dz * gx, -dz * gy))
    return out_a, out_J, out_Jx


def fit_one(a, th, x, sigma, oriented, max_iter, tol, vertex_cov, min_cos, chi2_2):
    """Fit one pencil (estimator.fit_pencil for batch shape ()).

    a, th, sigma: lists of N floats, the line angles, spoke angles and angle sigmas [rad];
    x: (2,) normalised vertex; oriented, max_iter, tol [rad]: as `estimator.refine_pencil`;
    vertex_cov: (2, 2) or None; min_cos: `defaults.MIN_COS`; chi2_2: the detection
    threshold (`defaults.CHI2_2_DETECTION`). Returns a dict of the PencilFit fields (numpy
    arrays of batch shape ()), or raises ValueError("degenerate").
    """
    N = len(a)
    x0, x1 = float(x[0]), float(x[1])
    w = [1.0 / (s * s) for s in sigma]
    sw = [1.0 / s for s in sigma]
    ct = [math.cos(t) for t in th]
    st = [math.sin(t) for t in th]
    nrm, v, Q = _virtual_rotation(x0, x1)
    bx = [Q[0][0] * math.cos(ai) + Q[0][1] * math.sin(ai) for ai in a]
    by = [Q[1][0] * math.cos(ai) + Q[1][1] * math.sin(ai) for ai in a]
    R = _closed_form(bx, by, ct, st, w, sw, Q, oriented, min_cos)
    R, J, Jx, res, cost, converged, it = _refine(R, a, x0, x1, ct, st, sw, max_iter, tol)
    R, Rt, J, Jx = _twins_in_order(R, v, x0, x1, ct, st, J, Jx)
    resid = [res[k] / sw[k] for k in range(N)]
    cov, var_tilt, var_normal = _covariance(R, J, Jx, w, v, nrm, vertex_cov)
    chi2_0 = _frontal(a, th, bx, by, Q, x0, x1, ct, st, w, sw)
    dof = N - 3
    inflate = inflation(cost, dof)
    detectable = (chi2_0 - cost) / inflate > chi2_2
    vx, vy, cq = v
    tilt = math.acos(min(max(R[0][2] * vx + R[1][2] * vy + R[2][2] * cq, -1.0), 1.0))
    sw_sum = sum(w)
    rms = math.sqrt(sum(w[k] * resid[k] * resid[k] for k in range(N)) / sw_sum)
    Ra, Rta = np.array(R), np.array(Rt)
    return dict(
        R_cam_from_target=Ra, R_twin=Rta, normal=Ra[:, 2].copy(), normal_twin=Rta[:, 2].copy(),
        ray=np.array(v), tilt=np.asarray(tilt), tilt_sigma=np.asarray(math.sqrt(max(var_tilt, 0.0))),
        normal_sigma=np.asarray(math.sqrt(max(var_normal, 0.0))), cov=np.asarray(cov),
        residuals=np.array(resid), rms=np.asarray(rms), chi2=np.asarray(cost), chi2_frontal=np.asarray(chi2_0),
        detectable=np.asarray(bool(detectable)), lines_used=np.asarray(N), converged=np.asarray(bool(converged)),
        iterations=it, ambiguous=np.asarray(True),
    )


def _virtual_rotation(x0, x1):
    """(|(x0, x1, 1)|, unit vertex ray v (3,), Q (3x3)) with Q v = (0, 0, 1)
    (estimator._virtual_rotation)."""
    nrm = math.sqrt(1.0 + x0 * x0 + x1 * x1)
    vx, vy, cq = x0 / nrm, x1 / nrm, 1.0 / nrm
    kx, ky = vy, -vx
    f = 1.0 / (1.0 + cq)
    Q = ((1.0 - f * ky * ky, f * kx * ky, ky), (f * kx * ky, 1.0 - f * kx * kx, -kx), (-ky, kx, cq))
    return nrm, (vx, vy, cq), Q


def _closed_form(bx, by, ct, st, w, sw, Q, oriented, min_cos):
    """Start rotation R (3x3 tuples) from the DLT and the signed SVD of its 2x2 block
    (estimator._closed_form); bx, by: the lines' directions in the virtual camera."""
    N = len(bx)
    rows, cbs, sbs = [], [], []
    for k in range(N):
        nb = math.hypot(bx[k], by[k])
        cb, sb = bx[k] / nb, by[k] / nb
        cbs.append(cb)
        sbs.append(sb)
        rows.append((sb * ct[k] * sw[k], sb * st[k] * sw[k], -cb * ct[k] * sw[k], -cb * st[k] * sw[k]))
    A = np.array(rows)
    evals, evecs = np.linalg.eigh(A.T @ A)
    if evals[1] <= 1e-12 * evals[3]:
        raise ValueError("degenerate")
    ha, hb, hc, hd = (float(v) for v in evecs[:, 0])
    if oriented:
        agree = sum(w[k] * ((ha * ct[k] + hb * st[k]) * cbs[k] + (hc * ct[k] + hd * st[k]) * sbs[k]) for k in range(N))
        if agree < 0:
            ha, hb, hc, hd = -ha, -hb, -hc, -hd
    E, F, G, H_ = (ha + hd) / 2, (ha - hd) / 2, (hc + hb) / 2, (hc - hb) / 2
    q, r = math.hypot(E, H_), math.hypot(F, G)
    a1, a2 = math.atan2(G, F), math.atan2(H_, E)
    th0, ph = (a2 - a1) / 2, (a2 + a1) / 2
    cos_g = min(max((q - r) / max(q + r, 1e-300), min_cos), 1.0)
    sin_g = math.sqrt(1.0 - cos_g * cos_g)
    cp, sp, c0, s0 = math.cos(ph), math.sin(ph), math.cos(th0), math.sin(th0)
    Rp = ((cp * c0 - sp * cos_g * s0, -cp * s0 - sp * cos_g * c0, sp * sin_g),
          (sp * c0 + cp * cos_g * s0, -sp * s0 + cp * cos_g * c0, -cp * sin_g),
          (sin_g * s0, sin_g * c0, cos_g))
    return _matmul(_transpose(Q), Rp)


def _refine(R, a, x0, x1, ct, st, sw, max_iter, tol):
    """Levenberg-Marquardt from R (estimator.refine_pencil).

    Returns (R, J, Jx, res, cost, converged, iterations): the model's Jacobians at R, the
    weighted residuals res (N,) and their sum of squares.
    """
    N = len(a)
    alpha, J, Jx = _model(R, x0, x1, ct, st)
    res = [sw[k] * _wrap_line(a[k] - alpha[k]) for k in range(N)]
    cost = sum(v * v for v in res)
    lam = 1e-4
    it = 0
    for it in range(1, max_iter + 1):
        h00 = h01 = h02 = h11 = h12 = h22 = g0 = g1 = g2 = 0.0
        for k in range(N):
            j0, j1, j2 = J[k][0] * sw[k], J[k][1] * sw[k], J[k][2] * sw[k]
            h00 += j0 * j0; h01 += j0 * j1; h02 += j0 * j2  # noqa: E702
            h11 += j1 * j1; h12 += j1 * j2; h22 += j2 * j2  # noqa: E702
            g0 += j0 * res[k]; g1 += j1 * res[k]; g2 += j2 * res[k]  # noqa: E702
        floor = 1e-12 * (h00 + h11 + h22) + 1e-300
        Hd = ((h00 * (1 + lam) + lam * floor, h01, h02), (h01, h11 * (1 + lam) + lam * floor, h12),
              (h02, h12, h22 * (1 + lam) + lam * floor))
        step, _, _ = _solve3(Hd, (g0, g1, g2))
        R_new = _matmul(_rotvec(*step), R)
        alpha_n, J_n, Jx_n = _model(R_new, x0, x1, ct, st)
        res_n = [sw[k] * _wrap_line(a[k] - alpha_n[k]) for k in range(N)]
        cost_n = sum(v * v for v in res_n)
        better = cost_n <= cost
        if better:
            R, J, Jx, res = R_new, J_n, Jx_n, res_n
        small = step[0] ** 2 + step[1] ** 2 + step[2] ** 2 < tol * tol
        stalled = better and (cost - cost_n) <= 1e-14 * cost
        if better:
            cost = min(cost, cost_n)
        lam = lam * (10.0 - 9.9 * better)
        if small or stalled or lam > 1e10:
            break
    return R, J, Jx, res, cost, lam <= 1e10, it


def _twins_in_order(R, v, x0, x1, ct, st, J, Jx):
    """(R, R_twin, J, Jx): the twin Rot(v, pi) R Rot(z, pi), and the one whose normal is
    closer to the optical axis first, with the Jacobians at it (estimator.fit_pencil)."""
    rot_ray = tuple(tuple(2.0 * v[i] * v[j] - (1.0 if i == j else 0.0) for j in range(3)) for i in range(3))
    Rt = _matmul(_matmul(rot_ray, R), ((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)))
    if Rt[2][2] > R[2][2]:
        R, Rt = Rt, R
        _, J, Jx = _model(R, x0, x1, ct, st)
    return R, Rt, J, Jx


def _quad(u, Mq, z):
    """u^T Mq z for short lists u, z and a nested-list matrix Mq."""
    return sum(u[i] * Mq[i][j] * z[j] for i in range(len(u)) for j in range(len(z)))


def _covariance(R, J, Jx, w, v, nrm, vertex_cov):
    """(cov 3x3 [rad^2], var_tilt, var_normal [rad^2]) of the fit R (estimator._covariance),
    on floats: 3x3 and 3x2 only. v: unit vertex ray; nrm = |(x, 1)|."""
    N = len(J)
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    a0 = a1_ = b0 = b1 = c0_ = c1 = 0.0  # rows of sum w J Jx^T
    for k in range(N):
        j0, j1, j2 = J[k]
        e0, e1 = Jx[k]
        wk = w[k]
        h00 += wk * j0 * j0; h01 += wk * j0 * j1; h02 += wk * j0 * j2  # noqa: E702
        h11 += wk * j1 * j1; h12 += wk * j1 * j2; h22 += wk * j2 * j2  # noqa: E702
        a0 += wk * j0 * e0; a1_ += wk * j0 * e1  # noqa: E702
        b0 += wk * j1 * e0; b1 += wk * j1 * e1  # noqa: E702
        c0_ += wk * j2 * e0; c1 += wk * j2 * e1  # noqa: E702
    ridge = 1e-14 * (h00 + h11 + h22)
    _, adj, det = _solve3(((h00 + ridge, h01, h02), (h01, h11 + ridge, h12), (h02, h12, h22 + ridge)), (0.0, 0.0, 0.0))
    Hi = [[adj[i][j] / det for j in range(3)] for i in range(3)]
    n = (R[0][2], R[1][2], R[2][2])
    nxv = (n[1] * v[2] - n[2] * v[1], n[2] * v[0] - n[0] * v[2], n[0] * v[1] - n[1] * v[0])
    sin_raw = math.sqrt(nxv[0] ** 2 + nxv[1] ** 2 + nxv[2] ** 2)
    sin_gg = max(sin_raw, 1e-12)
    g_rot = (-nxv[0] / sin_gg, -nxv[1] / sin_gg, -nxv[2] / sin_gg)
    var_tilt = _quad(g_rot, Hi, g_rot)
    cov = [row[:] for row in Hi]
    if vertex_cov is not None:
        Cx = np.asarray(vertex_cov, float).reshape(2, 2).tolist()
        hx = ((a0, a1_), (b0, b1), (c0_, c1))
        Gm = [[-sum(Hi[i][k] * hx[k][j] for k in range(3)) for j in range(2)] for i in range(3)]
        GC = [[sum(Gm[i][k] * Cx[k][j] for k in range(2)) for j in range(2)] for i in range(3)]
        for i in range(3):
            for j in range(3):
                cov[i][j] += GC[i][0] * Gm[j][0] + GC[i][1] * Gm[j][1]
        # d v_hat / d x = (I - v v^T)[:, :2] / |(x, 1)|
        P = [[((1.0 if i == j else 0.0) - v[i] * v[j]) / nrm for j in range(2)] for i in range(3)]
        g_x = [sum(g_rot[k] * Gm[k][j] for k in range(3)) - sum(n[k] * P[k][j] for k in range(3)) / sin_gg
               for j in range(2)]
        var_tilt += _quad(g_x, Cx, g_x)
    if sin_raw < 1e-9:
        var_tilt = math.inf
    # trace((I - n n^T) C (I - n n^T)) = trace(C) - n^T C n for a unit normal
    var_normal = cov[0][0] + cov[1][1] + cov[2][2] - _quad(n, cov, n)
    return cov, var_tilt, var_normal


def _frontal(a, th, bx, by, Q, x0, x1, ct, st, w, sw):
    """chi2 of the best frontal pencil (estimator._frontal): the in-plane angle in closed
    form, one Gauss-Newton step about the vertex ray."""
    N = len(a)
    Qt = _transpose(Q)
    b = [math.atan2(by[k], bx[k]) for k in range(N)]
    sn = cs = 0.0
    for k in range(N):
        gain2 = (Q[2][2] / (bx[k] * bx[k] + by[k] * by[k])) ** 2
        wv = w[k] / gain2
        e = 2.0 * (b[k] - th[k])
        sn += wv * math.sin(e)
        cs += wv * math.cos(e)
    phi = 0.5 * math.atan2(sn, cs)
    vhat = (Qt[0][2], Qt[1][2], Qt[2][2])

    def rot(p):
        c, s = math.cos(p), math.sin(p)
        return _matmul(Qt, ((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))

    al, Jf, _ = _model(rot(phi), x0, x1, ct, st)
    rf = [sw[k] * _wrap_line(a[k] - al[k]) for k in range(N)]
    jf = [sw[k] * (Jf[k][0] * vhat[0] + Jf[k][1] * vhat[1] + Jf[k][2] * vhat[2]) for k in range(N)]
    phi += sum(jf[k] * rf[k] for k in range(N)) / max(sum(j * j for j in jf), 1e-300)
    al, _, _ = _model(rot(phi), x0, x1, ct, st, jac=False)
    return sum((sw[k] * _wrap_line(a[k] - al[k])) ** 2 for k in range(N))
