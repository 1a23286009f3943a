"""Which band of an instrument is its shaft, where the border of the view cuts one of them: the
material cue's selection (`shaft.material_cue.select`).

An instrument enters the view from its border: its shaft is the part seen there, and its
wrist and jaws lie beyond the shaft's far end, along its axis. A shaft close to the lens is
wide and seen along few of its widths before its collar, while a jaw beyond it is narrow and
can be seen along many of its own widths, with two straight edges: as a band of the material
cue it looks more like a shaft than the shaft does. So where a band's run is cut by the
border of the view (`shaft.region_bands.RegionBand.reach_run`), a narrower band that lies
beyond that band's far end, within half its width of its axis, with its extension running into
that band's extension (the instrument's material continues from one into the other, over a
wrist between them too: where the far border cuts the jaw, its band reaches back to the wrist,
not to the shaft), is that instrument's distal
part (`beyond_entry`), not a shaft of its own, whether it ends inside the view or the border
cuts it too (an instrument that runs on out of the view past its jaws). No constant: the far
end, the band's own width and the extension's overlap (a tenth of the smaller area, as the
material cue's `_TOUCH`) say it; the narrower band (the wrist and jaws are narrower than the
shaft) is the part, so of two bands the border cuts the shaft is never dropped for its jaw.

Work pixels (the bands' own).

Example
-------
>>> import numpy as np
>>> from types import SimpleNamespace as NS
>>> def band(x0, x1, y, w, cut):   # a horizontal band from x0 to x1 at height y, width w
...     C = np.stack([np.arange(0.0, 100.0), np.full(100, y)], 1)
...     return NS(C=C, na=np.array([0.0, 1.0]), oi=np.full(100, -w / 2), oj=np.full(100, w / 2),
...               run=(x0, x1), ext=(0 if cut else x0 - 20, x1), view=(0, 100), reach_run=cut, width_run=float(w))
>>> def shaft(b):
...     from pencilcal.toolkit.detect.shaft.region_bands import band_polygon
...     return NS(band=b, poly_run=band_polygon(b), poly_ext=band_polygon(b, b.ext))
>>> sh, jaw = shaft(band(0, 30, 50.0, 30, True)), shaft(band(40, 70, 54.0, 6, False))
>>> [s is sh for s in beyond_entry([sh, jaw])]       # the jaw beyond the shaft's collar goes
[True]
"""
from __future__ import annotations

import numpy as np

__all__ = ["beyond_entry", "entry_and_far_end"]

#: A band's extension runs into another's where their hulls overlap by this fraction of
#: the smaller area (the material cue's `_TOUCH`, the same overlap).
_OVERLAP = 0.1


def _centre(band, k):
    """The middle of a band's cross-section at station k [work px]."""
    return band.C[k] + 0.5 * (band.oi[k] + band.oj[k]) * band.na


def entry_and_far_end(band):
    """(entry (2,), far (2,)) [work px]: the middles of a band's run at the end the border
    of the view cuts (the nearer the end of its observable stretch) and at the other end.

    >>> import numpy as np
    >>> from types import SimpleNamespace as NS
    >>> b = NS(C=np.stack([np.arange(10.0), np.zeros(10)], 1), na=np.array([0.0, 1.0]), oi=np.full(10, -2.0),
    ...        oj=np.full(10, 2.0), run=(6, 10), view=(0, 10))
    >>> [p.tolist() for p in entry_and_far_end(b)]
    [[9.0, 0.0], [6.0, 0.0]]
    """
    i0, i1 = band.run
    v0, v1 = band.view
    ends = (i0, i1 - 1) if i0 - v0 <= v1 - i1 else (i1 - 1, i0)
    return _centre(band, ends[0]), _centre(band, ends[1])


def _hull(poly):
    import cv2

    return cv2.convexHull(np.asarray(poly, np.float32))[:, 0, :]


def _beyond(sh, t):
    """Whether the band of sh (a `shaft.material_cue.MaterialShaft`) lies beyond the far end
    of t's, whose run the border cuts, within half t's width of its axis, its extension running
    into t's extension (module docstring)."""
    import cv2

    entry, far = entry_and_far_end(t.band)
    d = far - entry
    L = float(np.linalg.norm(d))
    if L <= 0:
        return False
    d = d / L
    i0, i1 = sh.band.run
    c = _centre(sh.band, (i0 + i1 - 1) // 2) - far
    if float(c @ d) <= 0 or abs(float(c[0] * d[1] - c[1] * d[0])) > 0.5 * t.band.width_run:
        return False
    P, Q = _hull(sh.poly_ext), _hull(t.poly_ext)
    area = min(abs(cv2.contourArea(P)), abs(cv2.contourArea(Q)))
    return area > 0 and cv2.intersectConvexConvex(P, Q)[0] > _OVERLAP * area


def beyond_entry(shafts):
    """The material cue's shafts (`shaft.material_cue.MaterialShaft`, best first) without
    those that are the distal part of an instrument whose shaft the border cuts (module
    docstring): a band beyond the far end of a wider one whose run the border cuts."""
    cut = [t for t in shafts if t.band.reach_run]
    return [sh for sh in shafts
            if not any(t is not sh and t.band.width_run > sh.band.width_run and _beyond(sh, t) for t in cut)]
