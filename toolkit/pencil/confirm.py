"""Whether anything confirms a radial target's labelling of its spokes.

A few edges of a star labelled with the wrong spokes can fit their angles as well as the
right ones (chi2 within its dof): a labelling of under half the spokes is reported only
where a prior, the spoke radii or the circles about the vertex confirm it.
`orient.orient_segments` asks `unconfirmed_labelling` of each labelling it reports;
`detect.radial.trimmed_at_spokes_end` asks `unconfirmed_final` of the orientation it keeps,
once every edge was searched for, and `few_spokes_final` of the orientation it keeps.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.pencil.orientation import Orientation

__all__ = ["UNCONFIRMED_SPOKES", "FEW_SPOKES", "unconfirmed_labelling", "unconfirmed_final", "few_spokes_final"]


#: A labelling of fewer than this share of a pencil's spokes that neither a prior, the radii nor
#: the circles confirm is not reported (`unconfirmed_labelling`).
UNCONFIRMED_SPOKES = 0.5

#: A radial target's final orientation that uses fewer than this share of its pencil's spokes
#: is not reported (`few_spokes_final`).
FEW_SPOKES = 0.25


def unconfirmed_labelling(pencil, spokes, resolved_by, circle_points, circ, circle_consistent=None, grown=None):
    """Raise EstimationError where a labelling nothing confirms may be wrong: under
    `UNCONFIRMED_SPOKES` of the pencil's spokes (spokes: (K,) the spokes of the lines the
    search labelled; lines the labelling grew to confirm nothing), circle points given (at
    least `circle.MIN_POINTS`), and either the twin left open with the points fitting no
    circle about the fitted plane or one that chooses neither twin, or the twin chosen by
    circles whose normal disagrees with the chosen one (circle_consistent False: the
    circle_chi2 of the record beyond its detection quantile) where the labelling grown
    (grown: (L,) the spokes of every line used) also holds under `UNCONFIRMED_SPOKES`. A
    small, steeply tilted star's few edges labelled with the wrong spokes fit their angles
    (chi2 within its dof), and only the rings show it: about a right labelling they choose
    its twin (circ: the circles' `CircleEstimate` or None; chosen, resolved_by is "circle").
    Example: 6 of 64 spokes, twin open, 40 circle points and no circle -> "ambiguous
    labelling: ...".
    """
    from pencilcal.toolkit.pencil.circle import MIN_POINTS

    n_pts = 0 if circle_points is None else np.asarray(circle_points, float).reshape(-1, 2).shape[0]
    n_spokes = int(np.unique(spokes).size)
    if n_pts < MIN_POINTS or n_spokes >= UNCONFIRMED_SPOKES * pencil.count:
        return
    # a circle that chooses neither twin confirms nothing either: a 64-wedge star's 8 edges
    # labelled as 6 wrong spokes (the normal 72 deg off) had one about that plane
    if resolved_by is None:
        what = "fit no circle about that plane" if circ is None else "fit a circle that chooses neither twin"
    # nor do circles that choose the twin nearer their normal but agree with neither: a
    # 64-wedge star's 11 rim edges labelled a quarter turn off (7 spokes, the normal 22 deg
    # off) had circles 10 deg from the twin chosen, their chi2 112. The circles' chi2 alone
    # says too little: right labellings of every spoke exceed it too, and so did a right one
    # grown from 7 searched spokes to 52; a wrong one found nothing to grow to
    elif resolved_by == "circle" and circle_consistent is False and grown is not None \
            and np.unique(grown).size < UNCONFIRMED_SPOKES * pencil.count:
        what = "choose a twin whose normal they disagree with"
    else:
        return
    raise EstimationError(
        f"ambiguous labelling: {n_spokes} of {pencil.count} spokes labelled, "
        f"{'the twin open' if resolved_by is None else 'the twin chosen by the circles'}, and the "
        f"{n_pts} circle points {what}: not a measurement")


def unconfirmed_final(rec, pencil):
    """rec, a radial target's final `Orientation` (`detect.radial.trimmed_at_spokes_end`), or a
    refused one where under `UNCONFIRMED_SPOKES` of the spokes are used, their twin chosen by
    circles that agree only within the lines' looser sigma (9 of 64 at 2.05 deg, the circles'
    0.83 deg, 4.8 deg away: the normal 4.4 deg off); never a first one, whose gaps are searched."""
    if not (rec.ok and rec.resolved_by == "circle" and rec.circle_consistent
            and rec.spokes_used is not None and rec.spokes_used < UNCONFIRMED_SPOKES * pencil.count
            and rec.circle_normal_sigma_deg is not None and rec.normal_sigma_deg > rec.circle_normal_sigma_deg):
        return rec
    return Orientation(image=rec.image, ok=False, model=rec.model,
                       spokes=None if rec.spokes is None else np.full(np.shape(rec.spokes), -1), error=(
        f"ambiguous labelling: {rec.spokes_used} of {pencil.count} spokes labelled, the twin chosen by the circles, "
        f"which agree with the lines' normal only within its sigma of {rec.normal_sigma_deg:.2f} deg, looser than "
        f"theirs ({rec.circle_normal_sigma_deg:.2f} deg): that confirms no labelling; not a measurement"))


def few_spokes_final(rec, pencil):
    """rec, a radial target's final `Orientation` (`detect.radial.trimmed_at_spokes_end`), or a
    refused one where it uses under `FEW_SPOKES` of the pencil's spokes in the end (a star's
    missing edges searched for). Resting on so few, the fit's sigma holds the edges' noise but not a vertex
    walked off or spokes labelled a wedge off: a small 64-wedge star's 6 spokes within 146 deg
    gave a normal 4.8 deg off (sigma 3.0 deg), another's 13 within 68 deg 1.25 deg off (sigma
    0.89). Example: 6 of 64 spokes -> "too few spokes: 6 of 64 used (under 25%) ...".
    """
    if not (rec.ok and rec.spokes_used is not None and rec.spokes_used < FEW_SPOKES * pencil.count):
        return rec
    return Orientation(image=rec.image, ok=False, model=rec.model,
                       spokes=None if rec.spokes is None else np.full(np.shape(rec.spokes), -1), error=(
        f"too few spokes: {rec.spokes_used} of {pencil.count} used (under {FEW_SPOKES:.0%}): so few may be "
        f"labelled or centred wrongly beyond their sigma; not a measurement"))
