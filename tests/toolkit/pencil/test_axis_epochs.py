"""Pivot epochs in 3-D (toolkit/pencil/axis_epochs.py): the change-point test on shafts' 3-D
axes seen by a moving camera, and the F(k, nu) tail it uses (`epochs.f_sf`).

Each frame's camera is the reference's moved by lambda t_k (t_k in the map unit, lambda
= 12 mm) and turned by up to 3 deg (handed over as R_frame_from_ref, t_frame_from_ref); its shaft's axis passes through the fulcrum, is
noised in its chart by its covariance (0.3 deg, 0.3 mm across and 2 mm along the line of
sight: the depth from the diameter is the weak one) and handed over in its own frame's
camera with the exact pose (no pose noise: the test's scale is the axes').
"""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.pencil.axis_epochs import axis_epochs
from pencilcal.toolkit.pencil.cylinder import axis_frame
from pencilcal.toolkit.pencil.epochs import f2_sf, f_sf

LAMBDA = 12.0


def sequence(rng, fulcrums, per):
    """(points, directions, covs, R, t, pose_cov, frame_of) of `per` frames about each
    fulcrum (3,) in turn [mm, reference camera], one axis a frame."""
    F = np.repeat(np.asarray(fulcrums, float), per, axis=0)
    n = len(F)
    d = rng.normal(size=(n, 3)) * [1.0, 1.0, 0.4]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d *= np.sign(d[:, 2:3] + 1e-9)
    R = rotation_from_rotvec(np.radians(rng.uniform(-3, 3, (n, 3))))       # R_ref_from_frame
    t = rng.normal(size=(n, 3)) * [0.5, 0.5, 0.3]
    p_ref = F - 40.0 * d                                                    # a point of the shaft nearer the camera
    p = np.einsum("nji,nj->ni", R, p_ref - LAMBDA * t)                      # in the frame's camera
    dd = np.einsum("nji,nj->ni", R, d)
    E = axis_frame(p, dd)
    sd = np.array([np.radians(0.3), np.radians(0.3), 0.3, 2.0])
    # the weak offset along the line of sight: the chart's second offset made the depth's
    view = p / np.linalg.norm(p, axis=1, keepdims=True)
    e1 = view - np.sum(view * dd, -1, keepdims=True) * dd
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e0 = np.cross(dd, e1)
    B = np.einsum("nkc,njc->nkj", E, np.stack([e0, e1], 1))                 # chart axes in (e0, e1)
    Cs = np.einsum("nik,k,njk->nij", B, sd[2:] ** 2, B)
    C = np.zeros((n, 4, 4))
    C[:, :2, :2] = np.diag(sd[:2] ** 2)
    C[:, 2:, 2:] = Cs
    x = np.einsum("nij,nj->ni", np.linalg.cholesky(C), rng.standard_normal((n, 4)))
    p = p + x[:, 2:3] * E[:, 0] + x[:, 3:4] * E[:, 1]
    dd = dd + x[:, 0:1] * E[:, 0] + x[:, 1:2] * E[:, 1]
    R_frame_from_ref = np.swapaxes(R, 1, 2)
    return (p, dd / np.linalg.norm(dd, axis=1, keepdims=True), C, R_frame_from_ref,
            -np.einsum("nij,nj->ni", R_frame_from_ref, t), np.zeros((n, 6, 6)), np.arange(n))


def test_f_sf_is_the_f_distribution():
    from scipy.stats import f

    for k, F, nu in [(2, 4.2, 12), (4, 0.5, 3), (4, 3.1, 20), (6, 2.0, 40)]:
        assert f_sf(F, k, nu) == pytest.approx(f.sf(F, k, nu), rel=1e-9)
    assert f_sf(4.2, 2, 12) == pytest.approx(f2_sf(4.2, 12), rel=1e-12)
    with pytest.raises(InputError):
        f_sf(1.0, 3, 10)


@pytest.mark.slow
def test_the_3d_epochs():
    """12 frames about one fulcrum: no split in 12 draws (alpha 0.01); the fulcrum moved by
    15 mm across the view after frame 6: the split at 6 in each of 6 draws."""
    rng = np.random.default_rng(3)
    still = [axis_epochs(*sequence(rng, [[0.0, 0, 90]], 12), 12).bounds for _ in range(12)]
    moved = [axis_epochs(*sequence(rng, [[0.0, 0, 90], [15.0, 0, 90]], 6), 12).bounds for _ in range(6)]
    print(still, moved)
    assert sum(len(b) > 1 for b in still) == 0
    assert all(b == [(0, 6), (6, 12)] for b in moved)


def test_axis_epochs_checks_its_input():
    p, d, C, R, t, S, f = sequence(np.random.default_rng(0), [[0.0, 0, 90]], 6)
    with pytest.raises(InputError, match="frame indices"):
        axis_epochs(p, d, C, R, t, S, f, 5)
    with pytest.raises(InputError, match="min_frames"):
        axis_epochs(p, d, C, R, t, S, f, 6, min_frames=2)
