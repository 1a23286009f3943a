"""The shared dartboard photographs (../shared/data/real-radial-targets, no ground truth):
the plane from the sector boundaries against the plane from the rings, the camera estimated
from the board itself (`validation.radial_photos`). Nothing here was tuned on them. And the
lens's k1 from the boundaries' chi2 profile on rendered dartboards, where it is known."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.synth.radial import DARTBOARD, dartboard_layers, dartboard_pencil, radial_pose, render_layers
from pencilcal.validation.radial_photos import check_photo, nominal_camera, profile_k1
from tests.conftest import data_dir

# chi-square with 2 dof at the level of a 3-sigma Gaussian test (99.73 %)
CHI2_3SIGMA = -2.0 * np.log(1.0 - 0.9973)


# boundaries used, of 20: measured 16, 17 and 16 with k1 the minimum of the chi2 profile of a
# fixed labelled set and each edge's outer half-window left out of its line (docs/method.md;
# 17, 18 and 17 before that cut on earlier code, 15, 17 and 17 without it on this one; 18, 17
# and 16 when k1 was chosen among the counts of labelled boundaries), the floors one below, as
# the labelling's margin on the rest moves with the edges (the focal length a few thousandths
# of a px off gives 17 and 19 on the side views). No dart hides a boundary in any of the
# three: every boundary could be used. With each edge trimmed at the ring where the sectors
# end (`orient_radial_edges`): 16, 17 and 19; the far view's floor raised to one below (its
# three edges that ran into the numbers' ring now labelled), the others kept (at the cameras
# chosen before the trim, it gives 16, 16 and 19: the count's fragility on the side views).
# With the ring found on the image (its outer edge in the dark sectors' directions) and an
# edge trimmed only where the part beyond turns it: 16, 17 and 19 again, the planes 0.04,
# 0.05 and 0.20 deg apart (0.11, 0.11 and 0.31 before). With the turn tested against the
# inside part's sd alone (a print turned past the ring is trimmed, test_validate): 15, 17 and
# 19, the planes 0.08, 0.48 and 0.19 deg apart; the left view's floor one below again (14).
# With the vertex test allowing the offset the edges share (`radial._through_vertex`): 19, 19
# and 19, the planes 0.105, 0.085 and 0.135 deg apart; the side views' floors one below (18).
# Then still missing, each lost in the detection (crowded directions, docs/method.md), none
# hidden by a dart: the left view's boundary straight up, the right view's level with the bull
# on its left, the far view's down and to the right (a 17 px piece); 19, 18 and 19 measured
# later on the same code. With a faint direction beside a stronger one taken as its companion
# (a wire's side, `radial._companions`) and the bands chained closest pair first: 20, 19 and
# 20, the planes 0.163, 0.135 and 0.442 deg apart (chi2 0.17, 0.09 and 0.72); the floors one
# below. Still missing: one of the right view's, an edge 2.5-4.9 px off the vertex beside its
# wire (which one depends on the camera).
@pytest.mark.parametrize("name,spokes,tilt", [("dartboard_side_left", 19, (45, 65)),
                                              ("dartboard_side_right", 18, (45, 65)),
                                              ("dartboard_far", 19, (5, 25))])
def test_boundaries_and_rings_agree(name, spokes, tilt):
    img = cv2.imread(str(data_dir("real-radial-targets") / f"{name}.jpg"))
    r = check_photo(img, dartboard_pencil())
    o = r["orientation"]
    # k1 from the profile's curvature: 0.012, 0.013 and 0.084 measured (the frontal view's
    # boundaries constrain it least), each within the profile's span
    assert 0 < r["k1_sigma_nominal"] < 0.15 and -0.6 < r["k1_nominal"] < 0.4
    assert o.ok and o.resolved_by == "circle"
    # the side views' webcam: about 800 px (53 deg across 800 px), every ring saying so within
    # 5 %; the nearly frontal phone photograph fixes it far less well (its rings scatter)
    per = r["focal_per_circle"][np.isfinite(r["focal_per_circle"])]
    if name != "dartboard_far":
        assert 700 < r["focal_px"] < 900
        assert np.median(np.abs(per / r["focal_px"] - 1)) < 0.05
    # the two planes within three sigmas of their difference (the shared vertex counted once)
    assert r["circles_used"] >= 3 and r["circle_chi2"] <= CHI2_3SIGMA
    assert tilt[0] < o.tilt_deg < tilt[1]  # side views "strongly oblique, roughly 50-60 deg"; far: "nearly frontal"
    # the boundaries the orientation uses (of 20; the numbers' ring and a dart keep a few out)
    assert r["spokes_used"] >= spokes


# rendered dartboards as the webcam views see them (800x600, f 800 px, wires, numbers, blur,
# noise, gamma, uneven light, JPEG), the vertex off the image centre and tilted (there the
# profile is sharp), and near the centre and frontal, where distortion about the centre keeps
# lines through it straight and concurrent and only the angles' map tells k1: the cases were
# fixed before the first run; measured k1 -0.1486 +- 0.0047, -0.2483 +- 0.0075 and -0.049 +- 0.28
# (z 0.30, 0.23, 0.11), every boundary labelled: the sigma is small where the view says much
# and large where it says little
@pytest.mark.parametrize("k1,vertex,tilt,seed,sigma_range", [(-0.15, (470, 320), 50, 1, (0, 0.02)),
                                                             (-0.25, (330, 280), 55, 2, (0, 0.02)),
                                                             (-0.08, (400, 300), 15, 4, (0.05, 1.0))])
def test_profile_k1_on_renders(k1, vertex, tilt, seed, sigma_range):
    cam = nominal_camera(800, 600, 800, k1)
    R, t = radial_pose(cam, vertex, tilt, DARTBOARD["board"], fill=0.9, axis_deg=30, roll_deg=10)
    img = render_layers(cam, R, t, dartboard_layers(wires=True, numbers=True), blur_px=1.0, noise=2.0, gamma=2.2,
                        lighting=0.3, jpeg_quality=80, rng=seed)
    r = profile_k1(img, nominal_camera(800, 600, 800), dartboard_pencil())
    assert r["boundaries"] == 20 and r["chi2_dof"] < 3
    assert sigma_range[0] < r["k1_sigma"] < sigma_range[1]
    assert abs(r["k1"] - k1) < 3 * r["k1_sigma"]
