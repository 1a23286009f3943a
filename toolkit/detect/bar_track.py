"""Printed bars from frame to frame: the previous frame's bars are this frame's proposals.

A full bar detection (`bars.detect_bars`) proposes lines over the whole frame (a line
detector on the reduced image, merging, rough pairing, partners for lone edges) and then
refits the candidates; on a 1080p frame the proposals are most of its cost. In a video the
target moves a few pixels between frames, so `BarTracker` gives each frame the edges of the
bars the previous frame used as its candidates (`bars.find_bars` with a prior: each edge
looked for again within `bars.TRACK_SEARCH_PX`, of its own polarity), and measures them
exactly as a full detection does (refit, pairing, neighbours, caps): a tracked bar is the
same measurement of the same edge, from other stations along it.

The prior is checked, never trusted: the caller judges the frame by what it is for (the
orientation: `orient` falls back when the tracked frame's fit fails or uses fewer spokes
than the last full detection, less one) and calls `BarTracker.lost`, and the next call then
detects in full; so does every `REDETECT_FRAMES`-th frame (a spoke that came into view),
the first frame, and a frame of another size.

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

__all__ = ["BarTracker", "REDETECT_FRAMES"]

#: A full detection at least every this many frames (a second at 30 fps), whatever the prior.
REDETECT_FRAMES = 30


class BarTracker:
    """Bars frame after frame (module docstring). Call it on the frames in order.

    Attributes: ``tracked`` (frames whose bars came from the prior), ``full_used`` (what
    the caller kept of the last full detection, e.g. its number of spokes; None before).
    """

    def __init__(self, redetect_frames=REDETECT_FRAMES):
        self.redetect_frames = int(redetect_frames)
        self.tracked = 0
        self.full_used = None
        self._edges = None      # (M, 2, 4) raw px: the bars to look for in the next frame
        self._polarity = None   # what they were found as ("dark" or "light")
        self._shape = None
        self._since_full = 0
        self._last = None       # (bars, tracked) of the latest call

    def __call__(self, image, detector="auto", *, polarity="dark", **options):
        """This frame's bars and whether they were tracked: (Bars, bool). The keywords are
        `bars.detect_bars`' (detector, camera, min_length, width_px_range, valid_region, ...);
        give the same ones every frame."""
        shape = np.shape(image)[:2]
        use_prior = (self._edges is not None and len(self._edges) >= 2 and shape == self._shape
                     and self._since_full + 1 < self.redetect_frames)
        if use_prior:
            bars, _ = find_bars(image, detector, polarity=self._polarity, prior=self._edges, **options)
            self._since_full += 1
        else:
            bars, self._polarity = find_bars(image, detector, polarity=polarity, **options)
            self._since_full = 0
        self._shape = shape
        self._edges = bars.edges
        self._last = (bars, use_prior)
        self.tracked += bool(use_prior)
        return bars, use_prior

    @property
    def last_tracked(self):
        """Whether the latest call's bars came from the prior."""
        return bool(self._last is not None and self._last[1])

    def keep(self, mask, used=None):
        """After a full detection: only the bars `mask` (bool (M,) over its bars, e.g. the
        spokes the orientation used) are looked for in the next frames, and `used` is
        remembered (`full_used`, e.g. that number of spokes). After a tracked call every bar
        found stays: each was a spoke when last detected in full, and one that this frame's
        fit left out (an outlier this once) may be back in the next."""
        bars, tracked = self._last
        if not tracked:
            self._edges = bars.edges[np.asarray(mask, bool)]
            self.full_used = used

    def lost(self):
        """The latest call's bars did not do (the caller's judgement): the next call detects
        in full, and a tracked call is no longer counted as tracked."""
        if self._last is not None and self._last[1]:
            self.tracked -= 1
        self._edges = None
