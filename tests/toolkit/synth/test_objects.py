"""The instrument shaft: exact occlusion, converging silhouette edges, a metallic look."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.synth.objects import Instrument
from pencilcal.toolkit.synth.raster import render_coverage, target_coverage
from pencilcal.toolkit.synth.render import render_frame
from pencilcal.toolkit.synth.sheet import layout_sheet
from tests.toolkit.synth.helpers import board_pose, small_camera

SHEET = layout_sheet()


def test_instrument_occludes_with_exact_converging_edges():
    cam = small_camera("pinhole")
    R, t = board_pose(30.0, 330.0)
    ins = Instrument.in_plane(SHEET.pencil.vertex, height=4.5, angle_deg=100.0, radius=2.5, tip=60.0, back=300.0)
    plain = render_frame(cam, R, t, SHEET, background="plain")
    with_shaft = render_frame(cam, R, t, SHEET, background="plain", instrument=ins)
    cov = np.clip(target_coverage(cam, R, t, []) + 0, 0, 1)  # nothing: sanity of the helper
    assert cov.max() == 0
    outline = ins.outline(R, t)
    c_shaft = np.clip(render_coverage(cam, [(outline, 1)]), 0, 1)
    # occlusion: the image changes only where the shaft is
    changed = with_shaft != plain
    assert changed.sum() > 500
    assert np.all(c_shaft[changed] > 0)
    # the silhouette: along each row the shaft's width equals the distance between the two
    # exact tangent lines (pinhole: straight lines m . (x, y, 1) = 0 in normalised coords)
    m = ins.silhouette_planes(R, t)
    K = cam.K
    lines_px = m @ np.linalg.inv(K)  # lines in pixel coordinates
    F, a = ins.axis_cam(R, t)
    tip_px, back_px = cam.project(F + 30.0 * a), cam.project(F - 80.0 * a)
    widths, truth = [], []
    for v in np.arange(int(min(tip_px[1], back_px[1])) + 2, int(max(tip_px[1], back_px[1])) - 2):
        xs = sorted(-(L[1] * v + L[2]) / L[0] for L in lines_px)
        widths.append(c_shaft[v].sum())
        truth.append(xs[1] - xs[0])
    assert len(widths) > 50
    assert np.max(np.abs(np.array(widths) - truth)) < 1e-6
    # perspective: the silhouette edges are not parallel, they meet at the axis' vanishing point
    vp = np.cross(lines_px[0], lines_px[1])
    vanish = cam.K @ a
    assert np.allclose(vp[:2] / vp[2], vanish[:2] / vanish[2], rtol=1e-6)
    # the shaft looks metallic: a bright stripe and darker flanks
    vals = with_shaft[c_shaft > 0.999].astype(float)
    assert vals.max() - vals.min() > 60
