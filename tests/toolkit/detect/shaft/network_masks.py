"""Renders of an instrument with exact truth, and masks as a segmentation network gives them.

`render_case` renders frames of the pivot scenario as hard as real frames (colour, the
opencv lens's barrel distortion, uneven light, optical blur, sensor noise, JPEG) and gives
each frame's true silhouette lines (ideal px, from the scenario's silhouette planes) and an
imperfect mask of its instrument (`network_mask`): the exact coverage
(`Scenario.instrument_coverage`) shifted by up to `shift_px` and with its boundary wobbling
by about `wobble_px` (a smooth random field, correlated over ~15 px), thresholded at one
half: a network's mask, off by a pixel or two, never exact.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from pencilcal.toolkit.synth.scenarios import make_scenario


def network_mask(coverage, rng, shift_px=1.0, wobble_px=0.5):
    """(H, W) uint8 0/1: the coverage (H, W) moved by a random sub-pixel shift of up to
    shift_px in x and y, its boundary wobbling by ~wobble_px, thresholded at 0.5; its
    largest component."""
    import cv2

    H, W = coverage.shape
    dx, dy = rng.uniform(-shift_px, shift_px, 2)
    m = cv2.warpAffine(coverage.astype(np.float32), np.float32([[1, 0, dx], [0, 1, dy]]), (W, H),
                       flags=cv2.INTER_LINEAR)
    if wobble_px > 0:
        n = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), 15.0)
        n /= max(float(n.std()), 1e-9)
        # the blurred mask falls by ~0.27 a pixel across its edge: a field of sd 0.27 w
        # moves the 0.5 crossing by ~w px
        m = cv2.GaussianBlur(m, (0, 0), 1.5) + 0.27 * wobble_px * n
    out = (m >= 0.5).astype(np.uint8)
    k, lab, stats, _ = cv2.connectedComponentsWithStats(out)
    if k > 2:
        out = (lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    return out


def true_edges(sc, i):
    """(2, 3) the true silhouette lines of frame i's instrument in ideal pixels, a^2 + b^2 = 1."""
    L = np.asarray(sc.frames[i]["shaft_edges_normalized"], float)
    lines = L @ np.linalg.inv(np.asarray(sc.camera.K, float))
    return lines / np.hypot(lines[:, 0], lines[:, 1])[:, None]


def render_case(frames=6, seed=1, size=(960, 540), albedo=None, blur_px=1.5, noise=3.0, jpeg=75, lighting=0.4,
                shaft_radius=4.0, distance=250.0, shift_px=1.0, wobble_px=0.5):
    """(scenario, [(image, mask, true edges (2, 3))]) of a pivot sequence (module docstring);
    albedo: the shaft's diffuse reflectance (None: the renderer's 0.35)."""
    import cv2

    sc = make_scenario("pivot", frames, seed=seed, size=size, shaft_radius=shaft_radius, distance=distance)
    if albedo is not None:
        sc.instruments = [dataclasses.replace(x, albedo=albedo) for x in sc.instruments]
    rng = np.random.default_rng([seed, 7])
    out = []
    for i in range(frames):
        img = sc.render(i, noise=noise, blur_px=blur_px, lighting=lighting, color=True)
        if jpeg:
            img = cv2.imdecode(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg)])[1], cv2.IMREAD_COLOR)
        out.append((img, network_mask(sc.instrument_coverage(i), rng, shift_px, wobble_px), true_edges(sc, i)))
    return sc, out


def edge_errors(shaft, lines):
    """Per edge of a `MaskShaft` (2,): the largest distance [ideal px] of its two ends from
    the true silhouette line nearest to it."""
    out = []
    for e in np.asarray(shaft.ideal_edges, float).reshape(2, 2, 2):
        d = np.abs(e @ lines[:, :2].T + lines[:, 2])  # (2 ends, 2 lines)
        out.append(float(d[:, np.argmin(d.mean(0))].max()))
    return np.array(out)
