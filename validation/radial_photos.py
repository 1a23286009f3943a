"""Radial targets on real photographs with no ground truth: the plane from the spokes' edges
against the plane from the circles, with the camera estimated from the target itself.

A photograph of a dartboard (or a Siemens star with its outline) taken with a camera nobody
calibrated holds two measurements of its plane: the sector boundaries' image angles (the
pencil, `toolkit.pencil.orient`) and the rings' images (their pole-polar relation with the
centre, `toolkit.pencil.circle`). Both need the camera; the target itself gives it:

- the lens's distortion (k1, about the image centre): the boundaries are straight lines through
  one point whose image angles are a 1-D projective map of their known angles, whatever the
  camera's focal length; distortion breaks that map, so the k1 under which the pencil
  explains the boundaries best, among those explaining within two of the most
  (`straightest_k1`), is the estimate (it uses
  one degree of freedom of the boundaries' residuals, not their plane);
- the focal length: the rings' images meet the horizon (the polar of the centre) in the
  images of the plane's circular points, which lie on the image of the absolute conic: with
  an assumed focal length f0, each ring gives f = f0 sqrt(-(I_x^2 + I_y^2))
  (`circle.circular_points`), the principal point the image centre and the pixels square.

Neither uses the boundaries' angles, which then test the rings' plane: `check_photo` fits
both with the camera so estimated and reports their angle and its chi2 against their sigmas.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import EstimationError

__all__ = ["nominal_camera", "straightest_k1", "focal_from_circles", "check_photo"]


def nominal_camera(width, height, f=None, k1=0.0):
    """A camera of an image width x height with focal length f [px] (default: the width),
    the principal point in the middle, square pixels, radial distortion k1."""
    f = float(width if f is None else f)
    return Camera("opencv", int(width), int(height), [[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1]],
                  [float(k1), 0.0, 0.0, 0.0])


def _pencil_score(image, camera, pencil, edges):
    """(spokes used, -chi2 per degree of freedom) of the pencil fitted under `camera`: what
    `straightest_k1` weighs."""
    _, rec, _ = _orient(image, camera, pencil, edges, circles=False)
    if not rec.ok:
        return (0, -np.inf)
    return (int(rec.spokes_used), -float(rec.chi2) / max(int(rec.lines_used) - 3, 1))


def straightest_k1(image, camera, pencil, k1_range=(-0.5, 0.1), step=0.02, fine=0.01, slack=2):
    """The k1 (about camera's principal point, its focal length kept) under which the
    pencil's boundaries fit a pencil best: the least chi2 per degree of freedom among the
    values that use within `slack` spokes of the most any value uses, over k1_range in
    `step`, then around the best in `fine` steps. Returns (k1, [(k1, score)] of every value
    tried, score as `_pencil_score`).

    The count guards against a k1 that loses boundaries; the fit, not the count, picks among
    the rest: a spoke more or less (one edge's labelling margin) swung the most-spokes k1 by
    0.2-0.4 on the shared dartboard photographs, to values whose chi2 / dof was 3-10 times
    the best's. The count moves by a boundary or two between k1 0.02 apart, so the grid is
    that fine: at 0.1 it missed every value within one boundary of the most but one.
    """
    from pencilcal.toolkit.detect.lines import radial_edge_count

    edges = radial_edge_count(pencil)
    tried = [(float(k), _pencil_score(image, _with_k1(camera, k), pencil, edges))
             for k in np.arange(k1_range[0], k1_range[1] + 1e-9, step)]
    best = _best_fit(tried, slack)
    tried += [(float(k), _pencil_score(image, _with_k1(camera, k), pencil, edges))
              for k in best + fine * np.array([-1, 1])]
    if max(t[1] for t in tried)[0] < 3:
        raise EstimationError("the boundaries fit no pencil under any k1 tried")
    return _best_fit(tried, slack), sorted(tried)


def _best_fit(tried, slack):
    """The k1 of [(k1, (spokes, -chi2/dof))] with the least chi2 / dof among those within
    `slack` spokes of the most."""
    most = max(s[0] for _, s in tried)
    return max((t for t in tried if t[1][0] >= most - slack), key=lambda t: t[1][1])[0]


def _with_k1(camera, k1):
    return Camera(camera.model, camera.width, camera.height, camera.K, [float(k1), 0.0, 0.0, 0.0])


def focal_from_circles(estimate, vertex, f0):
    """The focal length [px] each circle of a `circle.CircleEstimate` (fitted in the
    normalised coordinates of a camera of focal length f0, the vertex's image there (2,))
    implies: (C,) f0 sqrt(-Re(I_x^2 + I_y^2)) of its circular points (NaN where not real)."""
    from pencilcal.toolkit.pencil.circle import circular_points

    out = []
    for C in estimate.conics:
        Ix, Iy = circular_points(C, vertex)
        s2 = -(Ix * Ix + Iy * Iy).real
        out.append(f0 * np.sqrt(s2) if s2 > 0 else np.nan)
    return np.array(out)


def _orient(image, camera, pencil, edges, circles=True):
    """Detected edges, their orientation and the circles' estimate for one camera (any
    circle about the vertex, listed in the pencil file or not: under a camera still to be
    found, the circles' radii on the plane are not yet in the file's ratios)."""
    from pencilcal.toolkit.detect.radial import detect_radial_edges
    from pencilcal.toolkit.pencil.circle import circle_estimate
    from pencilcal.toolkit.pencil.orient import orient_segments

    found = detect_radial_edges(image, camera, edges=edges, circles=circles)
    rec = orient_segments(camera, found.segments, pencil, angle_sigma=found.angle_sigma,
                          offset_sigma=found.offset_sigma, circle_points=found.circle_points, keep_lines=True)
    est = None
    if rec.ok and len(found.circle_points):
        xn = camera.normalized_from_pixels(found.circle_points)
        est = circle_estimate(xn[np.all(np.isfinite(xn), -1)], rec.lines["vertex"], rec.lines["vertex_cov"],
                              np.asarray(rec.R_cam_from_target), np.asarray(rec.R_cam_from_target_twin),
                              scale=float(camera.K[0, 0]))
    return found, rec, est


def check_photo(image, pencil, f0=None):
    """The plane of a radial target in a photograph from its spokes' edges and from its
    circles, the camera estimated from the target (module docstring).

    Returns a dict: k1_nominal (with the focal length f0, default the image width) and the
    scores of the values tried; focal_px (the circles' median) and each circle's; then, with that
    camera (k1 rescaled to keep the same pixel map), the `Orientation` (``orientation``),
    edges found and spokes used, and the agreement of the lines' normal with the circles'
    (circle_angle_deg, circle_chi2, circle_consistent, circles_used).
    """
    from pencilcal.toolkit.detect.lines import radial_edge_count

    img = np.asarray(image)
    H, W = img.shape[:2]
    f0 = float(W if f0 is None else f0)
    edges = radial_edge_count(pencil)
    k1, tried = straightest_k1(img, nominal_camera(W, H, f0), pencil)
    cam1 = nominal_camera(W, H, f0, k1)
    _, rec1, est1 = _orient(img, cam1, pencil, edges)
    if est1 is None:
        raise EstimationError("no circle about the vertex was found to estimate the focal length")
    per_circle = focal_from_circles(est1, rec1.lines["vertex"], f0)
    f = float(np.nanmedian(per_circle))
    cam = nominal_camera(W, H, f, k1 * (f / f0) ** 2)
    found, rec, _ = _orient(img, cam, pencil, edges)
    return {"k1_nominal": k1, "f0": f0, "k1_tried": tried, "focal_px": f,
            "focal_per_circle": per_circle, "camera": cam, "orientation": rec.replace(lines=None),
            "edges_found": len(found), "spokes_used": rec.spokes_used, "circles_used": rec.circles_used,
            "circle_angle_deg": rec.circle_angle_deg, "circle_chi2": rec.circle_chi2,
            "circle_consistent": rec.circle_consistent}
