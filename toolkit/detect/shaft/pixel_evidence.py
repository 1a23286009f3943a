"""Tissue is not an instrument: a detected band judged by the learned pixel map inside it.

The shaft detector's cues propose bands between two long edges; a pale tissue band (the
gallbladder, a bowel wall between fat and a fold) has them too. The pixel model
(`pixels.PixelModel`: colour and local texture relative to the frame's own medians, learned
on masked frames) tells instrument pixels from tissue far better than any single hand cue
(leave-one-source-out pixel AUC 0.87-0.99 on the masked real sources), but its map is
ragged at the outline. So it judges rather than locates: a band's *evidence* is the median
of the map over the middle 60 % of its width, `STATIONS` x `ACROSS` samples along its
midline, and a detection with less than `MIN_PIXEL_EVIDENCE` is dropped
(`detector.detect_shafts`' ``pixel_evidence``). The map is that of the work frame
(`pixels.WORK_PX` = 320 px on its longer side), evaluated only at the pixels the samples
read (`pixel_evidence`; the same values as the whole map's, `band_evidence`): about 3.5 ms
of CPU a 1080p frame, most of it the frame's medians and local windows, the reduced copy
sharing its pass over the full frame with the detector's work frame (`work.Reductions`; it
was 6 ms with a reduction of its own; 21 ms for the whole map; docs/performance.md).

How `MIN_PIXEL_EVIDENCE` was chosen (leave one source out, every threshold chosen on the
sources other than the one scored) and what it gives: docs/method.md, pixel evidence.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
>>> img = np.zeros((180, 320, 3), np.uint8); img[:] = (60, 80, 170)
>>> work = WorkFrame(img, None, Validity(None, img.shape[:2]), 320)
>>> p = np.zeros(work.shape, np.float32); p[80:100, :200] = 0.9                  # one instrument
>>> mids = np.array([[0.0, 89.5, 199.0, 89.5], [0.0, 30.0, 199.0, 30.0]])      # on it, on tissue
>>> band_evidence(p, work, None, mids, np.array([20.0, 20.0])).round(2).tolist()
[0.9, 0.0]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.pixels import WORK_PX, instrument_probability_at
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
from pencilcal.toolkit.detect.working import to_working_points
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.quantiles import median

__all__ = ["band_evidence", "pixel_evidence", "MIN_PIXEL_EVIDENCE", "STATIONS", "ACROSS", "INNER"]

#: The least evidence (median map inside the band) a detection must have; chosen on the
#: masked real sources (docs/method.md).
MIN_PIXEL_EVIDENCE = 0.1
#: Samples along the midline and across the band's inner part.
STATIONS, ACROSS = 24, 7
#: The fraction of the band's width sampled, about its midline (its outline is the map's
#: least certain part).
INNER = 0.6


def _sample_points(work, camera, midlines, widths):
    """Per band, its samples (K, 2) float32 [work px] inside the work frame (module
    docstring): `STATIONS` x `ACROSS` over the middle `INNER` of its width, those outside
    the frame left out; None for a band outside it or without a length."""
    mids = np.asarray(midlines, float).reshape(-1, 4)
    h, w = work.shape
    out = []
    for m, wd in zip(mids, np.asarray(widths, float).reshape(-1)):
        ends = to_working_points(camera, m.reshape(2, 2))
        a, b = work.to_work(ends)
        L = float(np.hypot(*(b - a)))
        if not np.isfinite(L) or L <= 0:
            out.append(None)
            continue
        n = np.array([a[1] - b[1], b[0] - a[0]]) / L
        half = 0.5 * INNER * float(wd) * work.mean_scale
        s = np.linspace(0.0, 1.0, STATIONS)[:, None, None]
        t = np.linspace(-half, half, ACROSS)[None, :, None]
        P = (a + s * (b - a) + t * n).reshape(-1, 2)
        ok = (P[:, 0] >= 0) & (P[:, 1] >= 0) & (P[:, 0] <= w - 1) & (P[:, 1] <= h - 1)
        out.append(P[ok].astype(np.float32) if ok.any() else None)
    return out


def _medians(p, points):
    """The median (N,) of the map p (h, w) float32 sampled bilinearly at each band's points
    (`_sample_points`), 0 where a band has none."""
    import cv2

    out = np.zeros(len(points))
    for k, P in enumerate(points):
        if P is not None:
            v = cv2.remap(p, np.ascontiguousarray(P[None, :, 0]), np.ascontiguousarray(P[None, :, 1]),
                          cv2.INTER_LINEAR)[0]
            out[k] = float(median(v))
    return out


def _read_pixels(points, shape):
    """(rows, cols) (M,) of the pixels a bilinear `cv2.remap` of an (h, w) map reads at the
    points (list of (K, 2) or None): each point's 2 x 2 neighbours, and one more either way
    where the point lies within 1/32 px (remap's own quantisation of the position) of a
    pixel's column or row."""
    h, w = shape
    P = [q for q in points if q is not None]
    if not P:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    P = np.concatenate(P).astype(float)
    lo = np.floor(P - 1.0 / 32.0).astype(np.intp)
    hi = np.floor(P + 1.0 / 32.0).astype(np.intp) + 1
    need = np.zeros((h, w), bool)
    for dy in range(3):
        for dx in range(3):
            x, y = lo[:, 0] + dx, lo[:, 1] + dy
            use = (x <= hi[:, 0]) & (y <= hi[:, 1]) & (x >= 0) & (y >= 0) & (x < w) & (y < h)
            need[y[use], x[use]] = True
    return np.nonzero(need)


def band_evidence(p, work, camera, midlines, widths):
    """The evidence (N,) of bands: the median of the map p over the middle `INNER` of each.

    p: (h, w) the map of the work frame `work` (`work.WorkFrame`); camera: Camera or None (the
    midlines are raw pixels, the work frame ideal ones); midlines: (N, 4) [raw px]; widths:
    (N,) [ideal px]. A band outside the work frame has evidence 0.
    """
    return _medians(np.asarray(p, np.float32), _sample_points(work, camera, midlines, widths))


def pixel_evidence(image, shafts, camera=None, valid_region=None, model=None, validity=None, reductions=None):
    """The evidence (N,) of detected shafts (`detector.Shaft`, or lines.json records with
    ``midline`` and ``width_px``) in a BGR frame (module docstring); model: a
    `pixels.PixelModel` (default the shipped one).

    The map is evaluated only at the pixels the bands' samples read: the same evidence as
    `band_evidence` of the whole map (`pixels.instrument_probability`) at a fraction of the
    cost. validity: the image's `work.Validity` (e.g. the shaft detector's work frame's),
    instead of making one from valid_region; reductions: the image's `work.Reductions`
    (the shaft detector's work frame's, whose pass over the full frame it shares) instead of
    its own.
    """
    img = np.asarray(image)
    if not len(shafts):
        return np.zeros(0)
    if img.ndim != 3:
        raise InputError(f"pixel evidence needs a colour (BGR) frame, got shape {img.shape}")
    validity = Validity(valid_region, img.shape[:2]) if validity is None else validity
    pw = WorkFrame(img, camera, validity, WORK_PX, reductions=reductions)
    get = (lambda s, k: s[k]) if isinstance(shafts[0], dict) else getattr
    mids = np.array([np.asarray(get(s, "midline"), float) for s in shafts])
    widths = np.array([float(get(s, "width_px")) for s in shafts])
    points = _sample_points(pw, camera, mids, widths)
    rows, cols = _read_pixels(points, pw.shape)
    p = np.zeros(pw.shape, np.float32)
    p[rows, cols] = instrument_probability_at(pw, rows, cols, model)
    return _medians(p, points)
