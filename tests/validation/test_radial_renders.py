"""Radial targets on rendered webcam frames with exact truth (`validation.radial_renders`):
spokes used, the twin, the normal's error against its bound and its sigma.

A Monte Carlo of 25 frames: five each of Siemens stars of 16, 32, 64 and 128 wedges and of
dartboards, dark on light and the reverse, tilts 15-60 deg, blur 0.6-1.5 px, noise, uneven
light, gamma 2.2, JPEG 70-95, k1 down to -0.3. The bounds below hold for this sample with
room for its size (a coverage of 25 frames scatters by 9 %); docs/method.md gives a 200-frame
run against the issue's figures. Measured on this sample, a star's edges all located jointly
with their neighbours and the blur fitted with them: every spoke used, 25 of 25 twins rightly
resolved, RMSE / bound 0.72, coverage 76 % (the 128-wedge stars' 3 of 5; before a negative
lag-1 correlation of the stations was believed in their sigmas, `radial_joint._MIN_RHO`: 0.69,
80 %; before their edges' outer ends were left out, `radial_joint.END_WINDOWS`: 0.74, 84 %, 2 of
5), the circles' normal RMSE 0.008 deg (with the blur measured and held: 0.69, 76 %, 0.007 deg).
Since the seed sets the first cycle's polarity (`radial_conditions`; this sample's polarities
all turned) and a star's wedges are fitted as wide as the lines say (`orient._printed_wedge`):
every spoke used, 25 of 25, RMSE / bound 0.81, coverage 72 %, circles 0.0078 deg.

And webcam photographs of a printed star (`photo_conditions`), harder than the renders, and as
hard as real ones (`photographic_conditions`)."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.validation.radial_renders import ideal_lines_trial, radial_conditions, radial_summary, radial_trial


@pytest.fixture(scope="module")
def trials():
    return [radial_trial(c) for c in radial_conditions(25, seed=3)]


def test_spokes_and_twin(trials):
    s = radial_summary(trials)
    assert s["ok"] == 25
    assert s["spokes_used"] >= 0.95
    assert s["twin_right"] >= 0.92 and s["twin_right"] == s["resolved"]  # resolved only ever rightly
    for t in trials:
        # a 128-wedge star's far side at a steep tilt: its edges, located jointly with their
        # neighbours, are found, but the labelling may leave a few out (docs/method.md)
        assert t.spokes_used >= (0.85 if t.kind == "star128" else 1.0) * t.spokes, (t.kind, t.conditions)


def test_normal_against_its_bound_and_sigma(trials):
    s = radial_summary(trials)
    assert s["ratio"] <= 1.3
    assert 0.45 <= s["coverage"] <= 0.9
    # the circles' own normal: within a few hundredths of a degree
    assert s["circle_rmse_deg"] < 0.05


def test_the_estimator_covers_independent_lines():
    """The estimator alone (`ideal_lines_trial`): a 128-wedge star of this sample detected once,
    its lines replaced 200 times by the exact lines with independent noise at the sigmas the
    detector reported. Its normal's chi2 is then as the covariance says: coverage within the
    binomial 95 % interval of 68.3 % for 200 draws (61-75 %), mean chi2 near 2 (its sd 0.14).
    Measured: 67.0 %, mean 2.00, 253 lines (the frame's detected lines: chi2 3.16, before
    their edges' outer ends were left out). The detected lines' excess on such stars came
    from those ends (docs/method.md)."""
    cond = next(c for c in radial_conditions(25, seed=3) if c["kind"] == "star128")
    r = ideal_lines_trial(cond, 200)
    assert r["lines"] >= 0.9 * 256
    cover = float(np.mean(r["chi2"] <= -2.0 * np.log(1.0 - 0.6827)))
    assert 0.58 <= cover <= 0.78, cover
    assert 1.6 <= float(np.mean(r["chi2"])) <= 2.5


@pytest.mark.parametrize("seed, polarity, least", [(9332, "dark", 124), (9340, "dark", 120)])
def test_an_edge_the_joint_fit_left_short_is_located_again(seed, polarity, least):
    """128-wedge stars whose edges were clear over 20-30 px: the joint fit from there dropped
    the outer end's stations and weak steps and kept under 20 px, and the edge was lost, with
    its spoke where both of a wedge's edges were (spokes used 114 and 96 of 128). Located
    again from JOINT_SIGMAS apart, as the crowded edges are: 127 and 123."""
    cond = radial_conditions(1, seed=seed, kinds=("star128",))[0]
    cond["polarity"] = polarity
    t = radial_trial(cond)
    assert t.ok and t.twin_right
    assert t.spokes_used >= least, t.spokes_used


def test_single_frame_draws_cover_both_polarities():
    """One frame a seed (or one of each target) was dark for every seed: the polarity
    alternated by the frame's index. Now the first cycle's polarity comes from the seed, the
    other draws as before, and a long draw stays half dark, half light."""
    single = [radial_conditions(1, seed=s)[0]["polarity"] for s in range(9400, 9420)]
    assert 0 < single.count("light") < 20  # all 20 dark before
    each = [c["polarity"] for s in range(9400, 9410) for c in radial_conditions(5, seed=s)]
    assert 0 < each.count("light") < 50  # one polarity a seed: 2 of these 10 seeds light
    long = radial_conditions(40, seed=9400)
    assert sum(c["polarity"] == "light" for c in long) == 20
    for a, b in zip(radial_conditions(3, seed=9401), radial_conditions(3, seed=9401, kinds=("star16",))):
        assert a["tilt_deg"] == b["tilt_deg"] and a["seed"] == b["seed"]  # the other draws: the seed's


def test_printed_wedges_with_dot_gain_are_exact():
    """The photograph's star (`radial_photo.gained_wedges`): each wedge's edges are lines at
    the dot gain's distance from the vertex, parallel to the file's edges, its apex on its
    centre line; with no gain, the file's wedges."""
    from pencilcal.toolkit.pencil.spec import pencil_from_dict
    from pencilcal.toolkit.synth.polygons import annular_sector
    from pencilcal.toolkit.synth.radial_photo import gained_wedges

    star = pencil_from_dict({"start_deg": 10, "step_deg": 22.5, "count": 16, "shape": "wedge", "radius": [0, 40]})
    h = star.wedge / 2
    for g in (0.3, -0.2):
        for th, poly in zip(star.angles, gained_wedges(star, g)):
            apex, first, last = poly[0], poly[1], poly[-1]
            for p, a, s in ((first, th - h, -1), (last, th + h, 1)):
                u, n = np.array([np.cos(a), np.sin(a)]), s * np.array([-np.sin(a), np.cos(a)])  # n: out of the wedge
                assert np.dot(p, n) == pytest.approx(g, abs=1e-9) and np.dot(apex, n) == pytest.approx(g, abs=1e-9)
                assert np.hypot(*p) == pytest.approx(40.0, abs=1e-9)
            c = np.array([np.cos(th), np.sin(th)])
            assert abs(c[0] * apex[1] - c[1] * apex[0]) < 1e-9
    plain = gained_wedges(star, 0.0)
    ref = [annular_sector(0.0, 40.0, th - h, th + h) for th in star.angles]
    assert all(np.allclose(p, q, atol=1e-9) for p, q in zip(plain, ref))


@pytest.fixture(scope="module")
def photos():
    """Eight webcam photographs of a printed 64-wedge star (`photo_conditions`, seed 9500:
    not looked at while anything was chosen), each oriented as `orient IMAGES` does."""
    from pencilcal.validation.radial_renders import photo_conditions, photo_trial

    return [photo_trial(c) for c in photo_conditions(8, seed=9500)]


def test_photographs_of_a_printed_star(photos):
    """Paper on a desk with clutter, uneven light, vignetting, a specular patch, dot gain,
    defocus and motion blur, noise, JPEG 60-85, k1 down to -0.3, markers and text beside the
    star, tilted 15-60 deg: the star's spokes used, the twin, the normal within its sigma,
    where the star spans 30 % of the frame's height or more (6 of these 8). Smaller (down to
    20 %: its 128 edges 5 px apart at its rim) it is found or not (docs/method.md).
    Measured: 375 of 384 spokes, 6 twins right, errors 0.3-1.5 sigmas; without the wedges'
    printed width fitted (`orient._printed_wedge`) one normal was 5.3 sigmas off (0.033 deg,
    sigma 0.0062; now 0.0087 deg)."""
    big = [t for t in photos if t.conditions["fill"] >= 0.3]
    s = radial_summary(big)
    assert len(big) == 6 and s["ok"] == 6 and s["spokes_used"] >= 0.95 and s["twin_right"] == 1.0
    for t in big:
        assert t.err_deg < 0.6 and t.err_deg < 3 * t.sigma_deg + 0.002, t.conditions


def test_photographs_sigmas_are_not_many_times_their_errors(photos):
    """The same six stars (30 % of the height or more): each normal's sigma within 4 times its
    bound (the lines' own sigmas at the truth), its error within it as above. The angle sds the
    covariance takes (`detect.radial_scatter.turned_sigma`) took the edges' whole scatter about the
    vertex as turns: a print's dot gain (every edge moved towards the paper) and the vertex's
    offset from the edges' own intersection (a wedge's two edges moved apart) are none, and the
    sigmas were 10-110 times the bound on frames 0, 4, 5, 6 and 7 (0.25 and 1.07 deg on 0 and
    4, errors 0.004 and 0.009 deg). Measured: 1.2-2.9 times, chi2 0.14-1.5; with the lines'
    misfit scaling their error variances (`pencil.bend`) 1.3-5.1 times, the bound then widened
    by the square root of the misfit's scale (the lines' own scatter) as the sigma is."""
    big = [t for t in photos if t.conditions["fill"] >= 0.3]
    ratios = [t.sigma_deg / (t.bound_deg * np.sqrt(t.misfit_scale or 1.0)) for t in big]
    assert len(big) == 6 and max(ratios) < 4.0, ratios


def test_a_small_star_keeps_the_vertex_its_segments_found():
    """A 64-wedge star 24 % of the frame's height (its 128 edges 5 px apart at the rim, 1.6 px
    of defocus: `photo_conditions(60, 410)`, the sixth under 30 %): its edges are clear of
    their neighbours only near the rim, and the short stretches there intersected 8 px from
    the vertex the frame's segments found to 0.001 px; about that point the next round found
    no edge and the frame had no orientation. A round's vertex now replaces the last only
    within 3 sds of it or where it is fixed at least as well (`radial_vertex.better_vertex`).
    Measured: 64 spokes, the twin right, 0.059 deg off (sigma 0.07)."""
    from pencilcal.validation.radial_renders import photo_conditions, photo_trial

    cond = [c for c in photo_conditions(60, 410) if 0.2 <= c["fill"] < 0.3][5]
    t = photo_trial(cond)
    assert t.ok and t.spokes_used >= 60 and t.twin_right
    assert t.err_deg < 3 * t.sigma_deg


def test_a_small_star_labelled_wrongly_is_not_reported():
    """A 64-wedge star 23 % of the frame's height tilted 58 deg (`photo_conditions(80, 420)`,
    frame 10): its 7 edges found were labelled with the wrong spokes (6 of 64, their angles'
    chi2 10.8 on 4 dof, the twin open, the normal 72 deg off) and reported as ok. The circle
    points (563) fit no circle about that plane, where they confirm every right labelling
    (`confirm.UNCONFIRMED_SPOKES`): "ambiguous labelling", not ok; with its short edges kept by
    their sigma (`detect.radial._usable`) it is now oriented rightly. Frame 4 (20 %, 41 deg):
    its 8 short edges labelled 6 spokes, the twin open, the 500 circle points fit no circle:
    not ok; with the short edges located again from the joint fit's blur it is oriented
    rightly (26 spokes, 0.05 deg off): either way never reported wrong. Frame 14 (23 %, 53
    deg): the circles resolve the twin: still ok."""
    from pencilcal.validation.radial_renders import photo_conditions, photo_trial

    conds = photo_conditions(80, 420)
    small = photo_trial(conds[4])
    assert not small.ok or (small.twin_right and small.err_deg < 0.6)
    for k in (10, 14):
        right = photo_trial(conds[k])
        assert right.ok and right.twin_right and right.err_deg < 0.6


def test_a_small_star_once_oriented_wrong_from_a_few_spokes_is_never_reported_wrong():
    """A 64-wedge star 21 % of the frame's height tilted 51 deg (`photo_conditions(80, 3000)`,
    frame 70): 6 spokes within 146 deg used, every edge searched for, the twin chosen by circles
    looser than the lines (3.6 deg against 3.0): reported ok, the normal 4.8 deg off. Under a
    quarter of the spokes the sigma does not hold a vertex walked off or a labelling a wedge
    off (`confirm.few_spokes_final`): "too few spokes", not ok (with the short edges located
    again from the joint fit's blur, 4 spokes labelled: "ambiguous labelling", not ok). The
    rounds had walked its vertex 6.4 px off; with the edges located again about where the
    jointly located ones meet (0.2 px off) it is oriented rightly: 45 spokes, the twin right,
    0.24 deg off at a sigma of 0.25 deg. Either way never reported wrong."""
    from pencilcal.validation.radial_renders import photo_conditions, photo_trial

    t = photo_trial(photo_conditions(80, 3000)[70])
    assert not t.ok or (t.twin_right and t.spokes_used >= 16 and t.err_deg < min(0.5, 3 * t.sigma_deg))


def test_circles_of_a_few_short_arcs_do_not_choose_the_twin():
    """A 64-wedge star 22 % of the frame's height tilted 37 deg (`photo_conditions(80, 420)`,
    frame 78): every spoke used, but the circle points made 5 circles of 14-21 points (0.5-0.9
    px rms) about the wrong twin's plane, consistent among themselves, and chose it (74 deg
    off). The circles now choose only with a circle of `circle.DECISIVE_POINTS` points: the
    twin is left open, the closer one 0.057 deg from the truth."""
    from pencilcal.validation.radial_renders import photo_conditions, photo_trial

    t = photo_trial(photo_conditions(80, 420)[78])
    assert t.ok and t.spokes_used == 64
    assert not t.resolved or t.twin_right
    assert t.err_deg < 0.2


def test_nested_rings_grouped_by_the_wrong_twin_do_not_choose_it():
    """A 64-wedge star 25 % of the frame's height tilted 17 deg (`photo_conditions(80, 760)`,
    frame 78), the vertex 2.1 px off (its sd 0.2 px): the circle points of the two edges of its
    outline, grouped at the wrong twin's radii, made 7 loose circles about that twin's plane
    and chose it (34 deg off, chi2 0.5 against 8736). Chained on the image they are two whole
    rings nearer the right twin, which overrule them (`circle.circle_estimate`): the twin is
    not the wrong one. Measured: ok, 44 spokes, the twin open (the lines' normal's sigma 14.6
    deg), the nearer twin 0.57 deg off."""
    from pencilcal.validation.radial_renders import photo_conditions, photo_trial

    t = photo_trial(photo_conditions(80, 760)[78])
    assert t.ok and t.spokes_used >= 40
    assert not t.resolved or t.twin_right
    assert t.err_deg < 1.0


def test_circles_cut_across_chains_do_not_choose_the_twin():
    """A 64-wedge star 27 % of the frame's height tilted 51 deg
    (`photographic_conditions(40, 1200)`, frame 30): 4 circles of 12-32 points, grouped at
    one radius of the wrong twin from pieces of the points' chains, chose it (78 deg off);
    its outline is a chain of 98 points that does not go all round. A grouped circle now
    counts only where it lies along the chains it takes points from (`circle.WHOLE_CHAINS`).
    Measured: not ok ("ambiguous labelling": 31 of 64 spokes, the twin open)."""
    from pencilcal.validation.radial_renders import photo_trial, photographic_conditions

    t = photo_trial(photographic_conditions(40, 1200)[30])
    assert not t.ok or not t.resolved or t.twin_right


def _oriented(cond):
    """The `Orientation` of the photograph of `cond` as `orient IMAGES` makes it
    (`detect.radial.orient_radial_edges`, the pencil file that gives the star's shape)."""
    from pencilcal.toolkit.detect.lines import radial_edge_count, radial_joint_mode
    from pencilcal.toolkit.detect.radial import orient_radial_edges
    from pencilcal.toolkit.io.images import with_grey
    from pencilcal.validation.radial_renders import photo_frame, photo_pencils

    img, cam, _, _ = photo_frame(cond)
    pen = photo_pencils(cond)[1]
    return orient_radial_edges(with_grey(img)[0], cam, pen, edges=radial_edge_count(pen),
                               joint=radial_joint_mode(pen))[1]


def test_circles_that_disagree_with_the_twin_they_chose_confirm_no_labelling():
    """A 64-wedge star 22 % of the frame's height tilted 26 deg (`photographic_conditions(40,
    900)`, frame 2, without its defocus): only 11 short edges at the rim found, labelled a
    quarter turn off (7 of 64 spokes, the normal 21.7 deg off), and the twin chosen by 5
    circles of 13-25 points whose normal was 10 deg from the twin chosen (circle_chi2 112)
    and 65 deg from the truth: reported ok (the rings chained on the image change nothing
    here). Circles that disagree with the normal they chose confirm no labelling that holds
    under half the spokes even grown (`orient.unconfirmed_labelling`): "ambiguous
    labelling", not ok. With the short edges located again from the joint fit's blur, 8 of 64
    spokes are labelled and the circles agree with them only within the lines' wider sigma
    (6.0 deg against 2.9): refused as unconfirmed by that agreement instead (the circles that
    disagree are tested on their own in tests/toolkit/pencil/test_orient.py)."""
    from pencilcal.validation.radial_renders import photographic_conditions

    rec = _oriented(dict(photographic_conditions(40, 900)[2], defocus_px=0.0))
    assert not rec.ok and "ambiguous labelling" in rec.error
    assert "disagree" in rec.error or "looser than theirs" in rec.error


def test_a_star_whose_circles_agree_only_within_the_lines_wide_scatter_is_never_reported_wrong():
    """A 64-wedge star 25 % of the frame's height tilted 44 deg (`photo_conditions(80, 2200)`,
    frame 46): 14 short edges at the rim in two opposite arcs, 4 spokes searched, grown to 9,
    none more found where the fit predicts them; 4 tight circles chose the right twin and lay
    4.8 deg from the normal chosen, yet within the sigmas (circle_chi2 6.9): the lines fixed
    the normal to 2.05 deg, the circles to 0.83. Reported ok 4.4 deg from the truth. Agreement
    within the lines' own wider scatter confirms no final labelling of under half the spokes
    (`confirm.unconfirmed_final`): "ambiguous labelling", not ok. With the short edges located
    again from the joint fit's blur, 12 of 64 spokes are used: refused as "too few spokes"
    (under a quarter) instead; the looser agreement is met by
    `photographic_conditions(40, 900)` frame 2 above. The rounds had walked its vertex 4.5 px
    off; with the edges located again about where the jointly located ones meet (0.07 px off)
    it is oriented rightly: 63 spokes, the twin right, 0.16 deg off at a sigma of 0.13 deg.
    Either way never reported wrong."""
    from pencilcal.validation.radial_renders import photo_conditions, photo_trial

    t = photo_trial(photo_conditions(80, 2200)[46])
    assert not t.ok or (t.twin_right and t.spokes_used >= 16 and t.err_deg < min(0.5, 3 * t.sigma_deg))


def test_circles_that_points_on_the_spokes_make_about_any_plane_choose_no_twin():
    """A 64-wedge star 12 % of the frame's width, blurred and tilted 35 deg
    (`photographic_conditions(40, 1500)`, frame 0): 16 edges found, the vertex 19 px off,
    14 spokes labelled with the normal 12.6 deg off, and the twin chosen by 29 "circles"
    (14-31 points each, 0.2-0.6 px about their ellipses) whose normal agreed with it
    (circle_chi2 1.3): reported ok. Those points are the rays' crossings of the wedges' edges,
    which fill a ring at any radius on any plane: grouped by the other twin's radii they made
    27 circles about that twin as tightly (`circle._about_any_plane`). They choose nothing,
    and the labelling, confirmed by nothing, is refused: "ambiguous labelling", not ok."""
    from pencilcal.validation.radial_renders import photographic_conditions

    rec = _oriented(photographic_conditions(40, 1500)[0])
    assert not rec.ok and "ambiguous labelling" in rec.error


def test_photographic_effects_are_exact():
    """`photographic_conditions`' effects keep the truth: a curled sheet's polygons drawn flat
    image where the bent sheet's points do (each vertex on the camera's ray through the bent
    point), the sheet touching the plane at the vertex; the print's contrast is the grey
    levels' Michelson contrast; chromatic aberration moves the red channel out and the blue
    one in by the drawn shift at the corners, the green one not at all; and the set's other
    draws are `photo_conditions`' own."""
    import cv2

    from pencilcal.toolkit.synth.radial_photo import colour_photo, curled, photo_layers
    from pencilcal.validation.radial_renders import _camera, photo_conditions, photo_pencils, photographic_conditions

    cam = _camera(-0.2)
    R = np.array([[1.0, 0, 0], [0, np.cos(0.6), -np.sin(0.6)], [0, np.sin(0.6), np.cos(0.6)]])
    t = np.array([10.0, -5.0, 400.0])
    square = np.array([[0.0, 0], [60, 0], [60, 60], [0, 60]])
    (polys, _), = curled([([square], 0.5)], R, t, 0.5, 30.0)
    d = np.array([np.cos(np.radians(30)), np.sin(np.radians(30))])
    flat = polys[0]
    assert len(flat) >= 240 and np.allclose(flat[0], 0.0)  # sides cut to 1 mm, the vertex unmoved
    # the bent sheet's point under each drawn vertex: the same pixel
    ref = np.array([[0.0, 0], [60, 0], [60, 60], [0, 60]])
    for k, p in enumerate(ref):
        z = 0.5 * (p @ d / 148.5) ** 2
        bent = R @ np.array([p[0], p[1], z]) + t
        drawn = R @ np.array([*flat[[0, 60, 120, 180][k]], 0.0]) + t
        assert np.allclose(bent[:2] / bent[2], drawn[:2] / drawn[2], atol=1e-12)
    cond = dict(photographic_conditions(1, 7)[0], contrast=0.6)
    lay = photo_layers(photo_pencils(cond)[0], cond, np.random.default_rng(0))
    ink, paper = lay[2 + cond["clutter"]][1], cond["paper"]  # the text and markers' ink
    assert ((paper / ink) ** (1 / 2.2) - 1) / ((paper / ink) ** (1 / 2.2) + 1) == pytest.approx(0.6)
    a = photographic_conditions(6, 11)
    assert all(c[k] == b[k] for c, b in zip(a, photo_conditions(6, 11)) for k in b)
    # a bright dot at the top-left corner, the centre at the middle: each channel's dot
    scene = np.zeros((120, 160))
    scene[9:12, 9:12] = 1.0
    img = colour_photo(scene, dict(ca_px=1.0), np.random.default_rng(0), (79.5, 59.5)).astype(float)
    corner = np.hypot(79.5, 59.5)
    for ch, sign in zip(range(3), (-1, 0, 1)):  # B, G, R
        w = (img[..., ch] / 255.0) ** 2.2  # linear light, as the channel was shifted
        yy, xx = np.mgrid[0:120, 0:160]
        c = np.array([(w * xx).sum(), (w * yy).sum()]) / w.sum()
        radial = (c - (79.5, 59.5)) @ np.array([-79.5, -59.5]) / corner
        assert radial - np.hypot(69.5, 49.5) == pytest.approx(sign * np.hypot(69.5, 49.5) / corner, abs=0.05)
    assert cv2.cvtColor(img.astype(np.uint8), cv2.COLOR_BGR2GRAY).shape == (120, 160)


@pytest.fixture(scope="module")
def hard_photos():
    """Eight photographs as hard as real ones (`photographic_conditions`, seed 9600: nothing
    was chosen on it), each oriented as `orient IMAGES` does."""
    from pencilcal.validation.radial_renders import photo_trial, photographic_conditions

    return [photo_trial(c) for c in photographic_conditions(8, seed=9600)]


def test_photographs_as_hard_as_real_ones(hard_photos):
    """The print's contrast 0.5-0.8, paper texture, a shadow's edge, sharpening halos,
    chromatic aberration in a colour JPEG and a curled sheet, over `photo_conditions`: where
    the star spans 30 % of the frame's height or more (7 of these 8) every spoke, the twin
    right, the normal well within 0.6 deg. Measured: 448 of 448 spokes, 7 twins right,
    errors 0.009-0.064 deg; their sigmas 0.007-0.033 deg are too small for a curled sheet
    (chi2 up to 94: a sheet 0.06 mm off its plane at the star's rim bends the edges by more
    than their noise, docs/method.md)."""
    big = [t for t in hard_photos if t.conditions["fill"] >= 0.3]
    s = radial_summary(big)
    assert len(big) == 7 and s["ok"] == 7 and s["spokes_used"] >= 0.95 and s["twin_right"] == 1.0
    assert max(t.err_deg for t in big) < 0.2


def test_a_small_star_no_edge_of_which_is_clear_is_still_a_star():
    """A 64-wedge star 21 % of the frame's height under 1.2 px of defocus and 1.8 px of
    motion blur (`photographic_conditions(6, 800)[5]`): its edges were seen in 128
    directions about a vertex 0.04 px from the truth, but none clear of its neighbours, and
    the frame was dropped as no radial target (`radial._CROWDED_DIRECTIONS`). Located with
    their neighbours: 64 spokes, the twin right, 0.15 deg off."""
    from pencilcal.validation.radial_renders import photo_trial, photographic_conditions

    t = photo_trial(photographic_conditions(6, 800)[5])
    assert t.ok and t.spokes_used >= 60 and t.twin_right and t.err_deg < 0.6


def test_real_photographs_effects_are_exact():
    """`real_photo_conditions`' effects keep the truth: a printer's banding is a gain of the
    drawn amplitude and period along the drawn direction on the target plane (a frontal view:
    the plane's point under each pixel known exactly); the defocus grows across the frame
    from its near radius to its far one along the drawn direction, the light kept; the set's
    other draws are `photographic_conditions`' own, every star count in turn."""
    from pencilcal.toolkit.camera.model import Camera
    from pencilcal.toolkit.synth.radial_photo import _varying_defocus, banding
    from pencilcal.validation.radial_renders import STAR_COUNTS, photographic_conditions, real_photo_conditions

    cam = Camera("pinhole", 320, 240, [[400.0, 0, 160.0], [0, 400.0, 120.0], [0, 0, 1]])
    g = banding(cam, np.eye(3), np.array([0.0, 0.0, 200.0]), 0.04, 3.0, 30.0, 0.5)
    yy, xx = np.mgrid[0:240, 0:320]
    u = ((xx - 160.0) * np.cos(np.radians(30)) + (yy - 120.0) * np.sin(np.radians(30))) * 200.0 / 400.0  # [mm]
    assert np.allclose(g, 1.0 + 0.04 * np.sin(2 * np.pi * u / 3.0 + 0.5), atol=1e-4)
    step = np.zeros((60, 200), np.float32)
    step[30:] = 1.0  # a level edge; the defocus grows along x from 0.5 px at x = 20 to 4 px at x = 180
    out = _varying_defocus(step, dict(defocus_px=0.5, defocus_far_px=4.0, focus_px=[20.0, 0.0, 0.0, 160.0]))
    width = [np.count_nonzero((out[:, x] > 0.05) & (out[:, x] < 0.95)) for x in (10, 100, 190)]
    assert width[0] < width[1] < width[2] and width[0] <= 2 and width[2] >= 6
    assert np.allclose(out[:, 10:190].sum(0), step[:, 10:190].sum(0), atol=1e-3)  # the light kept
    a, b = real_photo_conditions(8, 11), photographic_conditions(8, 11, STAR_COUNTS)
    assert [c["wedges"] for c in a] == list(STAR_COUNTS) * 2
    assert all(c[k] == d[k] for c, d in zip(a, b) for k in d if k not in ("shading", "vignette"))
    assert all(d["shading"] <= c["shading"] <= 1.5 * d["shading"] for c, d in zip(a, b))


def test_photographs_as_hard_as_the_shared_ones():
    """`real_photo_conditions(8, 3500)` (a defocus growing across the star, a printer's
    banding, stronger shading; 16, 36, 64 and 128 wedges, twice): what is reported is right
    (every twin, every normal within 0.6 deg of the truth) and the coarse stars (16, 36
    wedges) use every spoke. Measured: 16 and 36 wedges every spoke, 0.011-0.053 deg; 64
    wedges 64 spokes (45 % of the height, 0.079 deg) and a star of 23 % refused; 128 wedges
    every spoke at 54 % (0.017 deg) and a star of 24 % refused (docs/method.md)."""
    from pencilcal.validation.radial_renders import photo_trial, real_photo_conditions

    trials = [photo_trial(c) for c in real_photo_conditions(8, 3500)]
    assert all(t.twin_right and t.err_deg < 0.6 for t in trials if t.ok)
    coarse = [t for t in trials if t.spokes <= 36]
    assert len(coarse) == 4 and all(t.ok and t.spokes_used == t.spokes for t in coarse)
    assert sum(t.ok for t in trials) >= 6


def test_a_curled_sheets_normal_is_within_its_sigma():
    """`real_photo_conditions(3, 3001)[2]`: a 64-wedge star on a sheet curled 0.40 mm at the
    sheet's end (0.09 mm at the star's rim), every spoke used, 0.067 deg off. Its lines' own
    sigmas gave the normal 0.021 deg (chi2 23.9: beyond 3 sigmas); the bend its lines show
    (its chi2 91 on 3 dof, `pencil.bend`) widens it to about 0.06 deg, the error within 2
    sigmas, and the bound (the lines' own sds at the truth) is unchanged."""
    from pencilcal.validation.radial_renders import photo_trial, real_photo_conditions

    t = photo_trial(real_photo_conditions(3, 3001)[2])
    assert t.ok and t.twin_right and t.spokes_used == 64
    assert t.chi2 < 6.18, (t.chi2, t.sigma_deg, t.err_deg)
    assert t.sigma_deg < 0.1
