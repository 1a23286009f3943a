"""The far edge of a band found from one edge (`shaft.partner`): on renders with exact truth,
a dark shaft on dark tissue, blurred and noisy, with inner streaks, the far edge is the
silhouette (the outermost edge), not a streak; a seed on tissue with nothing beyond gives
no band; from a boundary of the shaft's own region turned round (`turned_round`), the far
silhouette of a close shaft converging under perspective by more than a region pair may,
with a shadow inside along its far side."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.detect.shaft.partner import partner_bands, turned_round
from pencilcal.toolkit.detect.shaft.regions import BoundaryLines
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame


def _render(angle_deg, width, streaks, blur, seed=0):
    """A (240, 320, 3) frame: dark reddish tissue, a dark grey band of `width` px through the
    centre at angle_deg, with bright streaks inside at the given fractions of the width;
    JPEG-compressed. Returns the frame, the band's unit direction, normal and the offsets of
    its two edges from the centre along the normal [px]."""
    rng = np.random.default_rng(seed)
    H, W = 240, 320
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    a = np.radians(angle_deg)
    u, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    c = np.array([W / 2 - 0.5, H / 2 - 0.5])
    t = (xx - c[0]) * n[0] + (yy - c[1]) * n[1]
    img = np.empty((H, W, 3))
    img[:] = (38, 45, 85)
    img += rng.normal(0, 4, (H, W, 1)) * np.array([1, 1, 1.5])  # tissue texture
    img = cv2.GaussianBlur(img, (0, 0), 3.0)
    inside = np.abs(t) <= width / 2
    img[inside] = (30, 32, 36)
    for f in streaks:  # thin specular streaks along the axis
        img[np.abs(t - f * width / 2) <= 1.5] = (90, 92, 96)
    img = cv2.GaussianBlur(img, (0, 0), blur) + rng.normal(0, 1.5, (H, W, 3))
    img = np.clip(img, 0, 255).astype(np.uint8)
    _, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR), u, n, c, (-width / 2, width / 2)


def _seed(u, n, c, offset, half_len=120.0):
    """One region boundary along the band's edge at `offset` [px], its region (n = (-u_y,
    u_x)) outside the band, on the -n side."""
    p = c + offset * n
    uu = u if (-u[1] * n[0] + u[0] * n[1]) < 0 else -u  # (-u_y, u_x) along -n: away from the band
    return BoundaryLines(p=p[None], u=uu[None], n=np.array([[-uu[1], uu[0]]]), lo=np.array([-half_len]),
                         hi=np.array([half_len]), support=np.array([2 * half_len]))


@pytest.mark.parametrize("angle_deg, width, blur", [(8.0, 40.0, 1.5), (-25.0, 56.0, 2.5), (60.0, 30.0, 2.0)])
def test_far_edge_is_the_silhouette(angle_deg, width, blur):
    img, u, n, c, (lo, hi) = _render(angle_deg, width, streaks=(-0.3, 0.35), blur=blur)
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
    lines, pairs, maps = partner_bands(wf, _seed(u, n, c, lo), 10.0, 100.0, 15.0, 1.5)
    assert len(pairs.i) >= 1
    # the pair whose far edge lies on the band's side of the seed
    far = [lines.p[j] + 0.5 * (lines.lo[j] + lines.hi[j]) * lines.u[j] for j in pairs.j]
    off = [float((q - c) @ n) for q in far]
    k = int(np.argmin([abs(o - hi) for o in off]))
    assert abs(off[k] - hi) <= 1.5, off                # the outer edge, not a streak (1.5 work px)
    turn = np.degrees(np.arccos(min(1.0, abs(float(lines.u[pairs.j[k]] @ u)))))
    assert turn <= 1.0
    B = maps[k]
    assert B[int(round(c[1])), int(round(c[0]))] or B[int(round(c[1] + 0.25 * width * n[1])),
                                                      int(round(c[0] + 0.25 * width * n[0]))]


def test_no_band_beyond_a_lone_edge():
    """A straight edge between two tissues (a fold's rim) with nothing beyond it: no far edge
    on its uniform side within the widths searched."""
    rng = np.random.default_rng(3)
    img = np.empty((240, 320, 3))
    img[:] = (40, 50, 90)
    img[:120] = (60, 80, 140)
    img = cv2.GaussianBlur(img + rng.normal(0, 1.5, img.shape), (0, 0), 1.5)
    img = np.clip(img, 0, 255).astype(np.uint8)
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
    seeds = _seed(np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([159.5, 119.5]), 0.0)
    _, pairs, _ = partner_bands(wf, seeds, 10.0, 100.0, 15.0, 1.5)
    assert len(pairs.i) == 0


@pytest.mark.parametrize("conv_deg, blur", [(18.0, 1.5), (22.0, 2.5)])
def test_inward_far_edge_of_a_converging_shaft(conv_deg, blur):
    """A dark shaft close to the lens, its edges converging by conv_deg (more than the material
    cue's region pairs, 15 deg), a darker shadow strip inside along its far edge, on dark
    tissue; the seed is its near edge as a boundary of the shaft's own region (n into the
    shaft). Turned round, the far edge found is the silhouette, at its convergence, not the
    shadow's inner edge."""
    rng = np.random.default_rng(5)
    H, W = 240, 320
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    # the near edge y = 60 (the shaft below it); the far edge through (160, 160), turned by conv_deg
    b = np.tan(np.radians(conv_deg))
    far_y = 160.0 - b * (xx - 160.0)
    img = np.empty((H, W, 3))
    img[:] = (40, 48, 88)
    img += cv2.GaussianBlur(rng.normal(0, 4, (H, W, 1)) * np.array([1, 1, 1.5]), (0, 0), 3.0)
    inside = (yy >= 60.0) & (yy <= far_y)
    img[inside] = (34, 36, 40)
    img[inside & (yy >= far_y - 12.0)] = (22, 23, 26)  # its shadowed far side
    img = np.clip(cv2.GaussianBlur(img, (0, 0), blur) + rng.normal(0, 1.5, (H, W, 3)), 0, 255).astype(np.uint8)
    _, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
    img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
    # the boundary of the shaft's region along its near edge, n = (-u_y, u_x) = (0, 1) into it
    seed = BoundaryLines(p=np.array([[10.0, 59.5]]), u=np.array([[1.0, 0.0]]), n=np.array([[0.0, 1.0]]),
                         lo=np.array([0.0]), hi=np.array([180.0]), support=np.array([180.0]))
    lines, pairs, _ = partner_bands(wf, turned_round(seed), 10.0, 150.0, 25.0, 1.5)
    assert len(pairs.i) == 1
    j = pairs.j[0]
    q = lines.p[j] + 0.5 * (lines.lo[j] + lines.hi[j]) * lines.u[j]
    assert abs(q[1] - (160.0 - b * (q[0] - 160.0))) <= 1.5          # on the silhouette (1.5 work px)
    turn = np.degrees(np.arctan2(abs(lines.u[j][1]), abs(lines.u[j][0])))
    assert abs(turn - conv_deg) <= 1.0
    # its region's boundary turned round is not searched at 15 deg of convergence: no far edge
    # at the silhouette
    lines, pairs, _ = partner_bands(wf, turned_round(seed), 10.0, 150.0, 15.0, 1.5)
    for j in pairs.j:
        q = lines.p[j] + 0.5 * (lines.lo[j] + lines.hi[j]) * lines.u[j]
        turn = np.degrees(np.arctan2(abs(lines.u[j][1]), abs(lines.u[j][0])))
        assert abs(turn - conv_deg) > 1.0


@pytest.mark.parametrize("blur", [1.5, 2.5])
def test_inward_far_edge_not_on_a_fold_beyond(blur):
    """A dark shaft entering the view at the left, its edges converging by 10 deg away from the
    border (perspective: it is nearest the lens there), on lit tissue with a fold beyond its
    far silhouette: a dark crease as dark as the shaft, 8 px wide, along a line that widens the
    band away from the border. Searched into the shaft's region from its near edge, the
    outermost edge of the shaft's polarity with the shaft's colour inside it is the crease's
    outer rim; with `from_border` that band is refused (a band entering the view does not widen
    away from the border), and the same shaft without the crease keeps its silhouette."""
    rng = np.random.default_rng(7)
    H, W = 240, 320
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    b = np.tan(np.radians(10.0))
    far_y = 150.0 - b * (xx - 100.0)           # the silhouette: 166 px at x = 10, 134 at x = 190
    fold_y = 185.0 + 0.1 * (xx - 10.0)         # the crease's outer rim: 19 px beyond it at x = 10, 69 at x = 190
    tissue = np.empty((H, W, 3))
    tissue[:] = (90, 80, 150)                  # lit tissue
    tissue += cv2.GaussianBlur(rng.normal(0, 4, (H, W, 1)) * np.array([1, 1, 1.5]), (0, 0), 3.0)
    noise = rng.normal(0, 1.5, (H, W, 3))
    # the boundary of the shaft's region along its near edge from the border (x = 10), n into it
    seed = BoundaryLines(p=np.array([[10.0, 59.5]]), u=np.array([[1.0, 0.0]]), n=np.array([[0.0, 1.0]]),
                         lo=np.array([0.0]), hi=np.array([180.0]), support=np.array([180.0]))

    def far_edges(crease, **kw):
        img = tissue.copy()
        if crease:
            img[(yy > fold_y - 8.0) & (yy <= fold_y)] = (45, 42, 60)
        img[(yy >= 60.0) & (yy <= far_y)] = (40, 40, 50)           # the shaft
        img = np.clip(cv2.GaussianBlur(img, (0, 0), blur) + noise, 0, 255).astype(np.uint8)
        _, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
        wf = WorkFrame(cv2.imdecode(buf, cv2.IMREAD_COLOR), None, Validity(None, (H, W)), target_px=320)
        lines, pairs, _ = partner_bands(wf, turned_round(seed), 10.0, 150.0, 25.0, 1.5, **kw)
        return [(lines.p[j] + 0.5 * (lines.lo[j] + lines.hi[j]) * lines.u[j], lines.u[j]) for j in pairs.j]

    # without the rule the far edge is the crease's rim
    (q, _), = far_edges(True)
    assert abs(q[1] - (185.0 + 0.1 * (q[0] - 10.0))) <= 1.5
    # with it, no band
    assert far_edges(True, from_border=True) == []
    # the shaft alone, from the border: its silhouette, converging by 10 deg
    (q, u), = far_edges(False, from_border=True)
    assert abs(q[1] - (150.0 - b * (q[0] - 100.0))) <= 1.5          # on the silhouette (1.5 work px)
    assert abs(np.degrees(np.arctan2(abs(u[1]), abs(u[0]))) - 10.0) <= 1.0


def test_band_map_along_the_seed_and_its_colour_map():
    """A band searched from a seed over part of a shaft's edge (along_seed) has its own map
    only across that stretch (the far edge was searched there alone), zero beyond it; the
    given colour map (`shaft.edge_pairs.colour_map`, a grey shaft's lightness half-weighted)
    is the one the map is made with."""
    from pencilcal.toolkit.detect.shaft.edge_pairs import colour_map

    img = np.zeros((240, 320, 3), np.uint8)
    img[:] = (40, 50, 90)
    img[100:130, :] = (35, 38, 42)
    img = cv2.GaussianBlur(img, (0, 0), 2.0)
    wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
    # the boundary above the shaft from x = 100 to 220 (n into the region above)
    seed = BoundaryLines(p=np.array([[220.0, 99.5]]), u=np.array([[-1.0, 0.0]]), n=np.array([[0.0, -1.0]]),
                         lo=np.array([0.0]), hi=np.array([120.0]), support=np.array([120.0]))
    calls = []

    def recorded(*args):
        calls.append(args)
        return colour_map(*args)

    _, whole, maps = partner_bands(wf, seed, 10.0, 80.0, 15.0, 1.0)
    _, pairs, along = partner_bands(wf, seed, 10.0, 80.0, 15.0, 1.0, colour_map=recorded, along_seed=True)
    assert len(whole.i) == len(pairs.i) == 1 and len(calls) == 1
    assert maps[0][115, 40] and maps[0][115, 280]  # the whole band without the restriction
    assert along[0][115, 160] and along[0][115, 105] and along[0][115, 215]
    assert not along[0][115, 40] and not along[0][115, 280] and not along[0][60, 160]
