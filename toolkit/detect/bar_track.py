"""Printed bars from frame to frame: each bar looked for where a motion model predicts it.

A full bar detection (`bars.detect_bars`) proposes lines over the whole frame (a line
detector on the reduced image, merging, rough pairing, partners for lone edges) and then
refits the candidates; on a 1080p frame the proposals are most of its cost. In a video the
target moves between frames, so `BarTracker` predicts where each bar's edges are in this
frame and gives them to `bars.find_bars` as its candidates, each searched within its
predicted uncertainty, and measures them exactly as a full detection does (refit, pairing,
neighbours, caps): a tracked bar is the same measurement of the same edge, from other
stations along it.

The motion model (`motion.EdgeMotion`): each edge's end points move with a constant
velocity, and each edge is searched within a few predicted sd of its prediction (the
process noise learnt from the innovations, at most half the way to the next bar); a bar new
in the view borrows the velocity of the bars near it. Before any velocity is known (the
frame after the first) the bars are detected in the region around where they were instead.

The prior is checked, never trusted: the caller judges the frame by what it is for (the
orientation: `orient` falls back when the tracked frame's fit fails or uses fewer spokes
than the last detection, less one) and calls `BarTracker.lost`; the next call then detects
the bars in the region around their prediction (`region_of`, the line detector on that part
of the frame only), and if that fails too, in the whole frame. The first frame, a frame of
another size and every `REDETECT_FRAMES`-th frame (a spoke that came into view; every
`REDETECT_SHORT_FRAMES`-th while fewer bars are followed than the latest detection kept: a
spoke the tracker lost, not one that left the view) are detected too: the periodic one in
the region around the prediction.

Example
-------
>>> tracker = BarTracker()                                      # doctest: +SKIP
>>> for frame in frames:                                        # doctest: +SKIP
...     bars, tracked = tracker(frame.image, camera=cam, min_length=30.0)
...     rec = orient_segments(cam, bars.segments, pencil)
...     tracker.keep(rec.spokes >= 0) if rec.ok else tracker.lost()
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.bars import find_bars
from pencilcal.toolkit.detect.motion import EdgeMotion

__all__ = ["BarTracker", "region_of", "REDETECT_FRAMES", "REDETECT_SHORT_FRAMES", "REGION_MARGIN"]

#: A detection at least every this many frames (a second at 30 fps), whatever the prior.
REDETECT_FRAMES = 30
#: ... and every this many while fewer bars are followed than a detection once kept (a spoke
#: lost to a frame's blur or glare comes back within a third of a second).
REDETECT_SHORT_FRAMES = 8
#: The region around a lost track's prediction: its bars' bounding box grown by this
#: fraction of its size on every side (plus the search), within the frame.
REGION_MARGIN = 0.5


def region_of(edges, shape, margin=REGION_MARGIN, pad_px=0.0):
    """The region (x0, y0, x1, y1) [raw px, ints, x1 and y1 excluded] around bars' edges
    (M, 2, 4): their bounding box grown by `margin` of its size and `pad_px` on every side,
    within an image of `shape` (H, W); None when the edges are none or not finite.

    >>> region_of(np.array([[[100.0, 100, 200, 100], [200, 110, 100, 110]]]), (480, 640), 0.25, 4.0)
    (71, 93, 230, 118)
    """
    p = np.asarray(edges, float).reshape(-1, 2)
    if p.size == 0 or not np.all(np.isfinite(p)):
        return None
    lo, hi = p.min(0), p.max(0)
    grow = margin * (hi - lo) + pad_px
    H, W = shape
    x0, y0 = np.floor(np.maximum(lo - grow, 0)).astype(int)
    x1, y1 = np.ceil(np.minimum(hi + grow + 1, [W, H])).astype(int)
    return (int(x0), int(y0), int(x1), int(y1)) if x1 > x0 and y1 > y0 else None


class BarTracker:
    """Bars frame after frame (module docstring). Call it on the frames in order.

    Attributes: ``tracked`` (frames whose bars came from the prediction and were kept),
    ``regional`` (frames detected in the region around the prediction), ``full_used``
    (what the caller kept of the last detection, e.g. its number of spokes; None before),
    ``motion`` (the `EdgeMotion`), ``last_mode`` ("track", "region" or "full": how the
    latest call found its bars).
    """

    def __init__(self, redetect_frames=REDETECT_FRAMES):
        self.redetect_frames = int(redetect_frames)
        self.tracked = 0
        self.regional = 0
        self.full_used = None
        self._most = 0  # the bars the latest detection's caller kept
        self.motion = EdgeMotion()
        self.last_mode = None
        self._polarity = None
        self._shape = None
        self._since_full = 0
        self._next = "full"  # how the next call finds its bars
        self._last = None  # the latest call's bars

    def __call__(self, image, detector="auto", *, polarity="dark", **options):
        """This frame's bars and whether they were tracked: (Bars, bool). The keywords are
        `bars.detect_bars`' (detector, camera, min_length, width_px_range, valid_region, ...);
        give the same ones every frame."""
        shape = np.shape(image)[:2]
        if shape != self._shape:  # another size: nothing carries over
            self.motion, self._most = EdgeMotion(), 0
        mode = self._next
        period = self.redetect_frames if len(self.motion) >= self._most else min(self.redetect_frames,
                                                                                  REDETECT_SHORT_FRAMES)
        if len(self.motion) < 2:
            mode = "full"
        elif mode == "track" and not self.motion.known.any():
            mode = "region"  # no velocity known yet: nothing to predict by
        elif mode == "track" and self._since_full + 1 >= period:
            mode = "region"
        roi = None
        if mode == "track":
            pred, search = self.motion.search()
            bars, _ = find_bars(image, detector, polarity=self._polarity, prior=pred, prior_search=search, **options)
            self._since_full += 1
        else:
            if mode == "region":
                pred, search = self.motion.search()
                roi = region_of(pred, shape, pad_px=float(np.max(search)))
            bars, self._polarity = find_bars(image, detector, polarity=self._polarity if roi is not None else polarity,
                                             roi=roi, **options)
            self._since_full = 0
            mode = "region" if roi is not None else "full"
        self._shape = shape
        self._last = bars
        self.last_mode = mode
        self._next = "track"
        return bars, mode == "track"

    @property
    def last_tracked(self):
        """Whether the latest call's bars came from the prediction."""
        return self.last_mode == "track"

    def keep(self, mask=None, used=None):
        """The latest call's bars did (the caller's judgement). After a detection only the
        bars `mask` (bool (M,) over its bars, e.g. the spokes the orientation used) are
        followed in the next frames, and `used` is remembered (`full_used`, e.g. that number
        of spokes). After a tracked call every bar found is followed: each was a spoke when
        last detected, and one that this frame's fit left out (an outlier this once) may be
        back in the next."""
        bars = self._last
        edges = bars.edges
        if self.last_mode == "track":
            self.tracked += 1
        else:
            self.regional += self.last_mode == "region"
            if mask is not None:
                edges = edges[np.asarray(mask, bool)]
            self.full_used = used
            self._most = len(edges)
        self.motion.update(edges)

    def lost(self):
        """The latest call's bars did not do (the caller's judgement): the next call detects
        them in the region around their prediction after a tracked call, in the whole frame
        after a detection. Returns whether another detection is worth trying on this frame."""
        again = self.last_mode != "full"
        self._next = "region" if self.last_mode == "track" else "full"
        if not again:
            self.motion.missed()
        return again
