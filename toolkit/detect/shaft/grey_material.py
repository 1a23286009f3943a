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
the real false bands' 0.68 and more): the tissue-colour test
(`shaft.tissue_colour.MAX_TISSUE_COLOUR`) applies to both. A bright band with little colour
is glare as often as metal (a specular sheet where two pale folds cross was one on the
synthetic frames, 0.39): the learned map alone keeps it.

Example
-------
>>> import numpy as np
>>> ev, tc = np.array([0.5, 0.03, 0.03, 0.0, 0.03]), np.array([1.0, 0.4, 0.9, -0.5, 0.4])
>>> kept(ev, tc, 0.1, 1.25, dark=np.array([True, True, True, True, False])).tolist()
[True, True, False, True, False]

Measured in docs/method.md (grey material): on fresh synthetic seeds 106 -> 130 of 333
hard shafts found, no false detection more; on the real sources nothing changes.
"""
from __future__ import annotations

import numpy as np

__all__ = ["GREY_TISSUE_COLOUR", "kept"]

#: The most tissue colour (`shaft.tissue_colour`) of a band kept without the learned map's
#: evidence (module docstring); chosen on the synthetic hard frames and the shared real
#: sources, not on cholec or endovis17.
GREY_TISSUE_COLOUR = 0.5


def kept(evidence, colour, min_evidence, max_colour, grey=GREY_TISSUE_COLOUR, dark=True):
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

    Returns (N,) bool.
    """
    ev = np.asarray(evidence, float)
    tc = np.asarray(colour, float)
    ok = np.ones(ev.shape, bool)
    if min_evidence is not None:
        ok &= (ev >= min_evidence) | ((tc <= grey) & dark) if max_colour is not None else ev >= min_evidence
    if max_colour is not None:
        ok &= tc <= max_colour
    return ok
