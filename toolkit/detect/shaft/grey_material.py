"""A band clearly greyer than the tissue is instrument material, whatever the learned map says.

The learned instrument map (`shaft.pixel_evidence`) was trained on the pixels of a few real
sources; a shaft unlike theirs (seen through haze or smoke, thin and distant, a black
grasper on shadowed tissue, metal mirroring the tissue around it) gets little evidence from
it: on the synthetic hard frames (`synth.hard_shafts`) the shafts the cues found had median
evidence 0.00-0.24, most under `shaft.pixel_evidence.MIN_PIXEL_EVIDENCE` (0.1), and were
dropped. Their colour still tells them: a shaft's tissue colour (`shaft.tissue_colour`: its
inside's chromaticity along the tissue's hue, as a fraction of the frame's median) is what
it mirrors or what haze casts on it, under the tissue's own; the bands of tissue with two
long edges that the cues also find (pale folds, shadowed gaps, a fold in haze) keep the
tissue's hue: 0.68 and more on the real sources (every detection of the cues, the judges
off, matching no instrument: dvrk-suturing, box-trainer, greenscreen, the hysterectomy and
phantom frames) and 0.95 and more on the synthetic frames without a shaft.

So a band passes the evidence test (`kept`) when its evidence reaches the least evidence, or
when it is darker than its sides (polarity "dark") and its tissue colour is at most
`GREY_TISSUE_COLOUR` (0.5: half the tissue's colour; the synthetic hard shafts' 0.34-0.62,
the real false bands' 0.68 and more) or at most `GREY_FLANK_RATIO` of the colour of the
tissue right beside it (`shaft.tissue_colour.flank_colour`, the lesser of its two flanks'): a
shadow keeps the colour of the tissue it falls on, so a dark band of tissue (a gap, a fold's
shadow) is as coloured as its flanks or more (0.9 and more of them on the real sources, 0.84
and more on the synthetic frames without a shaft), whereas a black shaft in that shadow
mirrors part of it only. The tissue-colour test (`shaft.tissue_colour.MAX_TISSUE_COLOUR`)
applies to all. A bright band with little colour is glare as often as metal (a specular sheet
where two pale folds cross was one on the synthetic frames, 0.39; a pale band of the phantom
0.42 of its flanks' colour): the learned map alone keeps it.

Example
-------
>>> import numpy as np
>>> ev, tc = np.array([0.5, 0.03, 0.03, 0.0, 0.03]), np.array([1.0, 0.4, 0.9, -0.5, 0.4])
>>> kept(ev, tc, 0.1, 1.25, dark=np.array([True, True, True, True, False])).tolist()
[True, True, False, True, False]
>>> kept([0.03, 0.03], [0.55, 0.55], 0.1, 1.25, flank=[1.0, 0.9]).tolist()      # in a shadow: 0.55, 0.61 of it
[True, False]

Measured in docs/method.md (grey material): on fresh synthetic seeds 106 -> 130 of 333
hard shafts found, no false detection more; on the real sources nothing changes.
"""
from __future__ import annotations

import numpy as np

__all__ = ["GREY_TISSUE_COLOUR", "GREY_FLANK_RATIO", "kept"]

#: The most tissue colour (`shaft.tissue_colour`) of a band kept without the learned map's
#: evidence (module docstring); chosen on the synthetic hard frames and the shared real
#: sources, not on cholec or endovis17.
GREY_TISSUE_COLOUR = 0.5
#: The most tissue colour of a dark band kept without the learned map's evidence, as a fraction
#: of its flanks' (`shaft.tissue_colour.flank_colour`, module docstring): the most that adds no
#: false detection on the synthetic hard frames of seeds 0-29 (docs/method.md), not chosen on
#: the real sources.
GREY_FLANK_RATIO = 0.58


def kept(evidence, colour, min_evidence, max_colour, grey=GREY_TISSUE_COLOUR, dark=True, flank=None,
         flank_ratio=GREY_FLANK_RATIO):
    """Which bands are instrument-like (module docstring).

    evidence, colour : (N,)
        Each band's pixel evidence and tissue colour (NaN colour: not measured, never grey).
    min_evidence, max_colour : float or None
        The least evidence and the most tissue colour (None: that test not made; without
        the colour, the evidence alone decides).
    grey : float
        The most tissue colour of a band kept without the evidence.
    dark : (N,) bool or bool
        Which bands are darker than their sides (`Shaft.polarity` "dark"): only those are
        kept without the evidence.
    flank : (N,) or None
        Each band's flanks' tissue colour (`shaft.tissue_colour.flank_colour`; NaN or None:
        not measured): a dark band at most flank_ratio of it is kept without the evidence.
    flank_ratio : float
        The most tissue colour of such a band as a fraction of its flanks'.

    Returns (N,) bool.
    """
    ev = np.asarray(evidence, float)
    tc = np.asarray(colour, float)
    ok = np.ones(ev.shape, bool)
    grey_ = tc <= grey
    if flank is not None:
        fl = np.asarray(flank, float)
        with np.errstate(invalid="ignore"):
            # a flank without the tissue's hue (the black periphery, another instrument) says nothing
            grey_ |= (fl > 0) & (tc <= flank_ratio * fl)
    if min_evidence is not None:
        ok &= (ev >= min_evidence) | (grey_ & dark) if max_colour is not None else ev >= min_evidence
    if max_colour is not None:
        ok &= tc <= max_colour
    return ok
