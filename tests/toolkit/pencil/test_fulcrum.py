"""The fulcrum of a pivoting instrument and its pivot plane, from a sequence of lines."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.frames import angle_between, rotation_about_axis, rotation_angle
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames, read_angles, sequence_lines, without_frame
from tests.helpers import hd_camera


def pivot_sequence(cam, rng, n=25, span_deg=60.0, noise_px=0.0, outliers=0):
    """An instrument pivoting in a plane about a fulcrum 150 mm in front of the camera."""
    fulcrum = np.array([-20.0, 10.0, 150.0])
    R = rotation_about_axis([0.3, 1.0, 0.1], np.radians(40)) @ rotation_about_axis([0, 0, 1.0], 0.5)
    angles = np.radians(np.linspace(-span_deg / 2, span_deg / 2, n)) + 1.0
    frames = []
    for k, th in enumerate(angles):
        d = R @ np.array([np.cos(th), np.sin(th), 0.0])
        seg = cam.project(np.stack([fulcrum + 20 * d, fulcrum + 70 * d])).ravel()
        segs = [seg + noise_px * rng.normal(size=4)]
        if k < outliers:
            segs.append(rng.uniform([0, 0, 0, 0], [1900, 1000, 1900, 1000]))
        frames.append({"image": f"{k:03d}.png", "ok": True, "segments": np.array(segs)})
    return frames, angles, R, fulcrum


def test_noise_free(rng):
    cam = hd_camera()
    frames, angles, R, P = pivot_sequence(cam, rng)
    out = fulcrum_from_frames(cam, frames)
    np.testing.assert_allclose(out.vertex_px, cam.project(P), atol=1e-6)
    np.testing.assert_allclose(out.ray, P / np.linalg.norm(P), atol=1e-9)
    assert out.lines_used == 25 and out.outliers == []


def test_pivot_plane(rng):
    cam = hd_camera()
    frames, angles, R, P = pivot_sequence(cam, rng)
    out = fulcrum_from_frames(cam, frames, angles=angles)
    err = min(rotation_angle(np.asarray(out.pivot.R_cam_from_target), R),
              rotation_angle(np.asarray(out.pivot.R_cam_from_target_twin), R))
    assert np.degrees(err) < 1e-6
    assert out.pivot_frames == 25 and out.pivot.ambiguous is True


def test_noise_and_outliers(rng):
    """Noisy lines and 20% outlier segments: the fulcrum within its uncertainty."""
    cam = hd_camera()
    frames, angles, R, P = pivot_sequence(cam, rng, n=30, noise_px=0.5, outliers=6)
    out = fulcrum_from_frames(cam, frames, angles=angles)
    e = np.asarray(out.vertex_px) - cam.project(P)
    C = np.asarray(out.vertex_cov_px2)
    assert e @ np.linalg.solve(C, e) < 13.8  # chi2(2) at 99.9%
    assert len(out.outliers) >= 5
    n_err = min(angle_between(np.asarray(out.pivot.normal), R[:, 2]), angle_between(np.asarray(out.pivot.normal_twin), R[:, 2]))
    assert np.degrees(n_err) < 4 * out.pivot.normal_sigma_deg + 0.1


def test_shafts_preferred(rng):
    cam = hd_camera()
    frames, angles, R, P = pivot_sequence(cam, rng, n=10)
    for f in frames:
        f["shafts"] = [{"midline": f["segments"][0], "angle_sigma_deg": 0.05}]
        f["segments"] = np.array([[0.0, 0, 500, 10], [0, 5, 800, 30]])  # unrelated edges
    out = fulcrum_from_frames(cam, frames)
    np.testing.assert_allclose(out.vertex_px, cam.project(P), atol=1e-6)


def test_no_fulcrum(rng):
    cam = hd_camera()
    frames = [{"image": "a", "ok": True, "segments": np.array([[0.0, 0, 100, 0]])}]
    with pytest.raises(EstimationError, match="two"):
        fulcrum_from_frames(cam, frames)
    # parallel lines (with no lens distortion bending them) meet only at infinity
    par = [{"image": str(i), "ok": True, "segments": np.array([[0.0, 100 * i, 500, 100 * i]])} for i in range(5)]
    with pytest.raises(EstimationError, match="infinity|parallel"):
        fulcrum_from_frames(hd_camera("pinhole"), par)


def test_read_angles(tmp_path):
    (tmp_path / "a.csv").write_text("image,angle_deg\nb.png,20\na.png,10\n")
    np.testing.assert_allclose(read_angles(tmp_path / "a.csv", ["a.png", "b.png"]), np.radians([10, 20]))
    (tmp_path / "b.csv").write_text("10\n20\n")
    np.testing.assert_allclose(read_angles(tmp_path / "b.csv", ["x", "y"]), np.radians([10, 20]))
    with pytest.raises(InputError, match="2 angles for 3 frames"):
        read_angles(tmp_path / "b.csv", ["x", "y", "z"])
    with pytest.raises(InputError, match="no angle for image"):
        read_angles(tmp_path / "a.csv", ["a.png", "c.png"])
    (tmp_path / "c.csv").write_text("angle_deg\nten\n")
    with pytest.raises(InputError, match="numbers"):
        read_angles(tmp_path / "c.csv", ["x"])


def test_fulcrum_beyond_the_lens_model(rng):
    """An entry port 74 deg off the axis of a strongly distorted lens: its ray is exact, and
    its raw pixel, which the polynomial model cannot give there (it folds back before 74
    deg), is null rather than a number millions of pixels away."""
    cam = hd_camera()
    P = np.array([250.0, 10.0, 70.0])
    frames = []
    for k, th in enumerate(np.radians(np.linspace(-12, 12, 9))):
        d = rotation_about_axis([0.0, 1.0, 0.3], th) @ np.array([-0.93, 0.0, 0.37])
        seg = cam.project(np.stack([P + 190 * d, P + 240 * d])).ravel()
        assert np.all(np.isfinite(seg)) and np.all((seg >= 0) & (seg <= [1919, 1079] * 2))
        frames.append({"image": f"{k:03d}.png", "ok": True, "segments": seg[None]})
    out = fulcrum_from_frames(cam, frames)
    assert np.degrees(angle_between(out.ray, P)) < 1e-6
    assert out.vertex_px is None and out.vertex_cov_px2 is None
    # within the lens model's reach the raw pixel is given, and it is where the lens images it
    near = fulcrum_from_frames(cam, pivot_sequence(cam, rng)[0])
    assert near.vertex_px is not None


def test_a_frame_without_a_shaft_does_not_hand_its_edges_to_the_fulcrum(rng):
    """The documented two-step route (lines --shaft, then fulcrum --lines): one frame with
    no shaft but hundreds of edge segments must not outvote the others' midlines."""
    cam = hd_camera()
    frames, _, _, P = pivot_sequence(cam, rng, n=12, noise_px=0.3)
    for f in frames[1:]:
        f["shafts"] = [{"midline": f["segments"][0], "angle_sigma_deg": 0.05}]
    # frame 0: no shaft found, 450 edges of the scene meeting somewhere else
    other = np.array([300.0, 200.0])
    ang = rng.uniform(0, np.pi, 450)
    r0 = rng.uniform(20, 300, 450)
    d = np.stack([np.cos(ang), np.sin(ang)], -1)
    frames[0]["segments"] = np.concatenate([other + r0[:, None] * d, other + (r0 + 80)[:, None] * d], -1)
    frames[0]["shafts"] = []
    frames[1]["shafts"].append({"midline": np.array([np.nan, 0, 1, 1]), "angle_sigma_deg": 0.05})
    out = fulcrum_from_frames(cam, frames)
    assert out.lines_from == "shafts" and out.lines_used == 11
    assert np.linalg.norm(np.asarray(out.vertex_px) - cam.project(P)) < 5
    assert any("without a shaft" in w for w in out.warnings)
    assert any("non-finite" in w for w in out.warnings)
    assert out.to_dict()["lines_from"] == "shafts"


def test_without_frame_is_the_fit_of_the_other_frames(rng):
    """The jackknife's shortcut: a fit from all frames' lines less one frame's is the fit of
    the other frames, number for number (outliers named by their frame in the subset); None
    where the frame left out is the only one with shaft midlines."""
    cam = hd_camera()
    frames, angles, R, P = pivot_sequence(cam, rng, n=12, noise_px=0.5, outliers=3)
    lines = sequence_lines(cam, frames)
    for k in (0, 5, 11):
        rest = frames[:k] + frames[k + 1:]
        a = fulcrum_from_frames(cam, rest, np.delete(angles, k))
        b = fulcrum_from_frames(cam, rest, np.delete(angles, k), lines=without_frame(lines, frames, k))
        assert np.array_equal(a.ray, b.ray) and np.array_equal(a.vertex_cov_px2, b.vertex_cov_px2)
        assert np.array_equal(a.pivot.normal, b.pivot.normal) and a.outliers == b.outliers
        c = fulcrum_from_frames(cam, rest, np.delete(angles, k), raw_px=False)  # the ray alone: no raw pixel
        assert np.array_equal(a.ray, c.ray) and c.vertex_px is None and a.vertex_px is not None
    frames[4]["shafts"] = [{"midline": frames[4]["segments"][0], "angle_sigma_deg": 0.05}]
    assert without_frame(sequence_lines(cam, frames), frames, 4) is None
    assert without_frame(sequence_lines(cam, frames), frames, 3) is not None


def played_shafts(cam, rng, play_mm, n=50, angle_sigma_deg=0.02):
    """Shaft midlines of an instrument pivoting about a port 150 mm deep whose axis passes
    the fulcrum off by the port's play (play_mm sd per direction across the axis), each
    with a precise angle sigma of its own: the lines miss the fulcrum's image by the play's
    image, ~f play / depth px, whatever their own sigmas say."""
    fulcrum = np.array([-20.0, 10.0, 150.0])
    frames = []
    for k in range(n):
        d = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4), -1.0])
        d /= np.linalg.norm(d)
        off = rng.normal(0.0, play_mm, 3)
        off -= (off @ d) * d
        seg = cam.project(np.stack([fulcrum + off + 20 * d, fulcrum + off + 70 * d])).ravel()
        frames.append({"image": f"{k:03d}.png", "ok": True, "segments": np.zeros((0, 4)),
                       "shafts": [{"midline": seg, "angle_sigma_deg": angle_sigma_deg}]})
    return frames, fulcrum


def test_the_ports_play_is_in_the_fulcrums_sigmas(rng):
    """Shafts with precise midlines whose axes miss the fulcrum by the port's play: the
    fulcrum's image takes the play as an offset every line shares (``play``: its sd [px]
    about f play / depth), and its covariance holds the error, as the command writes it
    (with the noise step). A factor on the lines' own sigmas alone, its gate set for them,
    leaves the error far beyond its sigma (mean chi2 189 for 2 expected, 29 of 30 beyond 3.7 sigma)."""
    from pencilcal.toolkit.pencil.sequence_noise import fulcrum_noise

    cam = hd_camera()
    chi2, taus = [], []
    for _ in range(30):
        frames, P = played_shafts(cam, rng, 0.35)
        out, _ = fulcrum_noise(fulcrum_from_frames(cam, frames), inflate_only=True)
        e = np.asarray(out.vertex_px) - cam.project(P)
        chi2.append(e @ np.linalg.solve(np.asarray(out.vertex_cov_px2), e))
        taus.append(out.play["sigma_px"])
    expected = cam.K[0, 0] * 0.35 / 150.0
    print(f"mean chi2 {np.mean(chi2):.2f}, play {np.median(taus):.2f} px for {expected:.2f}")
    assert np.mean(chi2) < 3.0 and np.mean(np.array(chi2) > 13.8) < 0.05
    assert 0.6 * expected < np.median(taus) < 1.4 * expected
    # lines as precise as their sigmas say take no play
    frames, P = played_shafts(cam, rng, 0.0)
    assert fulcrum_from_frames(cam, frames).play["sigma_px"] == 0.0
