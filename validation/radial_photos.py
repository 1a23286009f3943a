"""Radial targets on real photographs with no ground truth: the plane from the spokes' edges
against the plane from the circles, with the camera estimated from the target itself.

A photograph of a dartboard (or a Siemens star with its outline) taken with a camera nobody
calibrated holds two measurements of its plane: the sector boundaries' image angles (the
pencil, `toolkit.pencil.orient`) and the rings' images (their pole-polar relation with the
centre, `toolkit.pencil.circle`). Both need the camera; the target itself gives it:

- the lens's distortion (k1, about the image centre): the boundaries are straight lines through
  one point whose image angles are a 1-D projective map of their known angles, whatever the
  camera's focal length; distortion breaks that map, so the k1 under which a fixed set of
  labelled boundaries fits a pencil best (the minimum of its chi2 profile, only the
  undistortion refitted: `profile_k1`) is the estimate, with a sigma from the profile's
  curvature (it uses one degree of freedom of the boundaries' residuals, not their plane);
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

__all__ = ["nominal_camera", "profile_k1", "focal_from_circles", "check_photo"]


def nominal_camera(width, height, f=None, k1=0.0):
    """A camera of an image width x height with focal length f [px] (default: the width),
    the principal point in the middle, square pixels, radial distortion k1."""
    f = float(width if f is None else f)
    return Camera("opencv", int(width), int(height), [[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1]],
                  [float(k1), 0.0, 0.0, 0.0])


def _labelled(image, camera, pencil, edges):
    """The edges detected under `camera` and the pencil's fit labelling them:
    (found, orientation with ``lines``, score (boundaries used, -chi2 per degree of freedom)).
    Untrimmed at the ring the spokes end on: trimmed, the side views' second round labelled
    a set whose profile ran to k1 -0.47 (chi2 / dof 128) from -0.16."""
    from pencilcal.toolkit.detect.radial import detect_radial_edges
    from pencilcal.toolkit.pencil.orient import orient_segments

    found = detect_radial_edges(image, camera, edges=edges, circles=False)
    rec = orient_segments(camera, found.segments, pencil, angle_sigma=found.angle_sigma,
                          offset_sigma=found.offset_sigma, circle_points=found.circle_points, keep_lines=True)
    score = (int(rec.spokes_used), -_chi2_dof(rec)) if rec.ok else (0, -np.inf)
    return found, rec, score


def _chi2_dof(rec):
    return float(rec.chi2) / max(int(rec.lines_used) - 3, 1)


def profile_k1(image, camera, pencil, k1_range=(-0.5, 0.1), coarse=0.1, span=(-0.6, 0.4), step=0.01, rounds=2):
    """The k1 (about camera's principal point, its focal length kept) under which a fixed set
    of labelled boundaries fits a pencil best, and its sigma.

    The boundaries are detected and labelled once per value of a coarse pass (k1_range in
    `coarse` steps); those of the value labelling the most (ties: the least chi2 per degree of
    freedom) are kept, their segments' raw end points, sigmas and labels fixed, and only the
    undistortion varies: the pencil is refitted to them under every k1 of `span` in `step`
    (`orient_segments` given the labels, no detection), a profile of chi2 smooth in k1, unlike
    the count of labelled boundaries, which jumps by one to twenty between values 0.02 apart.
    Its minimum (a parabola through it and its neighbours) is the estimate; its sigma, where
    the profile has risen by one from there, widened by sqrt(chi2 / dof) where that exceeds
    one (the lines' sigmas do not hold all of their scatter). The edges are then detected and
    labelled again at that k1 and profiled once more (`rounds` in all), as the end points
    were located straight under the labelling's k1.

    Returns a dict: k1, k1_sigma, chi2_dof (at the minimum of the last profile), boundaries
    (labelled in the last profile), coarse [(k1, (boundaries, -chi2/dof))], rounds [(k1 of
    the labelling, k1 of the minimum, k1_sigma, boundaries)] and profile (S, 3) [k1, chi2,
    lines used] of the last round.
    """
    from pencilcal.toolkit.detect.lines import radial_edge_count

    edges = radial_edge_count(pencil)
    tried = [(float(k), _labelled(image, _with_k1(camera, k), pencil, edges))
             for k in np.arange(k1_range[0], k1_range[1] + 1e-9, coarse)]
    k_lab, (found, rec, score) = max(tried, key=lambda t: t[1][2])
    if score[0] < 3:
        raise EstimationError("the boundaries fit no pencil under any k1 tried")
    grid = np.arange(span[0], span[1] + 1e-9, step)
    history = []
    for r in range(rounds):
        if r:
            k_lab = k1
            found, rec, score = _labelled(image, _with_k1(camera, k1), pencil, edges)
            if score[0] < 3:
                break
        prof = _chi2_profile(found, rec, camera, pencil, grid)
        k1, sigma, chi2_dof = _profile_minimum(prof)
        history.append((k_lab, k1, sigma, score[0]))
    return {"k1": k1, "k1_sigma": sigma, "chi2_dof": chi2_dof, "boundaries": history[-1][3],
            "coarse": [(k, t[2]) for k, t in tried], "rounds": history, "profile": prof}


def _chi2_profile(found, rec, camera, pencil, grid):
    """(S, 3) [k1, chi2, lines used] of the pencil refitted under each k1 of grid (S,) to
    the segments `found`, labelled as `rec` labelled them (NaN where the fit fails)."""
    from pencilcal.toolkit.pencil.orient import orient_segments

    labels = np.full(len(found), -1)
    labels[rec.lines["segment"]] = rec.lines["spoke"]
    out = []
    for k in grid:
        o = orient_segments(_with_k1(camera, k), found.segments, pencil, angle_sigma=found.angle_sigma,
                            offset_sigma=found.offset_sigma, labels=labels)
        out.append((k, o.chi2, o.lines_used) if o.ok else (k, np.nan, 0))
    return np.array(out, float)


def _profile_minimum(prof):
    """(k1, sigma, chi2 / dof) at the least chi2 of a profile (S, 3) [k1, chi2, lines]: a
    parabola through the least value and its two neighbours of the same line count (the
    count changes where a line leaves the vertex's pencil, a step in chi2), sigma where it
    has risen by one, widened by sqrt(chi2 / dof) when that exceeds one; at the span's end
    or where the parabola opens downwards, the grid value and an infinite sigma."""
    ok = np.isfinite(prof[:, 1])
    if not ok.any():
        raise EstimationError("the labelled boundaries fit no pencil under any k1 of the profile")
    i = int(np.nanargmin(np.where(ok, prof[:, 1], np.nan)))
    k, c, n = prof[i]
    dof = max(n - 3, 1)
    if 0 < i < len(prof) - 1 and np.all(prof[i - 1:i + 2, 2] == n):
        (a, b, c0) = np.polyfit(prof[i - 1:i + 2, 0] - k, prof[i - 1:i + 2, 1], 2)
        if a > 0:
            dk = -b / (2 * a)
            cmin = c0 - b * b / (4 * a)
            return float(k + dk), float(np.sqrt(1 / a * max(1.0, cmin / dof))), float(cmin / dof)
    return float(k), float("inf"), float(c / dof)


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


def _orient(image, camera, pencil, edges):
    """Detected edges, their orientation (`orient_radial_edges`: each edge that the print
    beyond the ring where the spokes end turns trimmed at it) and the circles' estimate for one camera (any circle about the
    vertex, listed in the pencil file or not: under a camera still to be found, the circles'
    radii on the plane are not yet in the file's ratios)."""
    from pencilcal.toolkit.detect.radial import orient_radial_edges
    from pencilcal.toolkit.pencil.circle import circle_estimate

    found, rec = orient_radial_edges(image, camera, pencil, edges=edges)
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
    prof = profile_k1(img, nominal_camera(W, H, f0), pencil)
    k1 = prof["k1"]
    cam1 = nominal_camera(W, H, f0, k1)
    _, rec1, est1 = _orient(img, cam1, pencil, edges)
    if est1 is None:
        raise EstimationError("no circle about the vertex was found to estimate the focal length")
    per_circle = focal_from_circles(est1, rec1.lines["vertex"], f0)
    f = float(np.nanmedian(per_circle))
    cam = nominal_camera(W, H, f, k1 * (f / f0) ** 2)
    found, rec, _ = _orient(img, cam, pencil, edges)
    return {"k1_nominal": k1, "k1_sigma_nominal": prof["k1_sigma"], "f0": f0,
            "k1_profile": prof, "focal_px": f,
            "focal_per_circle": per_circle, "camera": cam, "orientation": rec.replace(lines=None),
            "edges_found": len(found), "spokes_used": rec.spokes_used, "circles_used": rec.circles_used,
            "circle_angle_deg": rec.circle_angle_deg, "circle_chi2": rec.circle_chi2,
            "circle_consistent": rec.circle_consistent}
