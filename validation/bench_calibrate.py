"""`pencilcal bench --sections calibrate`: a calibration with its checks against OpenCV's.

``calibrate_vs_opencv_960x540``: 50 rendered 960x540 views of a chessboard of 12 x 9 squares
of 4.77 mm (11 x 8 inner corners, as on a da Vinci endoscope's calibration sets) through an
endoscope-like lens (barrel distortion, blur, sensor noise), encoded as PNG. pencilcal's side
is what `pencilcal calibrate` does with them: decode, detect the board, calibrate with the
board's warp and the corner-noise model, cross-validate on two halves, map the projection
uncertainty, judge (`validation.calibration_run.calibrate_checked`). OpenCV's side decodes
and detects the same way and runs ``cv2.calibrateCamera`` on the same corners. Target
<= 2.0. Beside it: ``calibrate_detect_s`` (decoding and detection, both sides),
``calibrate_fit_vs_opencv`` (the calibration alone over cv2.calibrateCamera alone) and
``calibrate_checks_s`` (the two halves, the maps and the verdict).

Example
-------
>>> cam, board = bench_camera(), bench_board()
>>> cam.size, board.inner_corners
((960, 540), (11, 8))
"""
from __future__ import annotations

import time

import numpy as np

__all__ = ["bench_calibrate", "bench_camera", "bench_board", "CALIBRATE_TARGETS"]

CALIBRATE_TARGETS = {"calibrate_vs_opencv_960x540": ("<=", 2.0)}


def bench_camera():
    """The bench's lens: 960x540, f = 760 px, an endoscope's barrel distortion."""
    from pencilcal.toolkit.camera.model import Camera

    return Camera("opencv", 960, 540, [[760.0, 0, 483.2], [0, 760.4, 268.9], [0, 0, 1]],
                  [-0.32, 0.14, 0.0006, -0.0004, -0.03])


def bench_board():
    """12 x 9 squares of 4.77 mm (11 x 8 inner corners)."""
    from pencilcal.toolkit.board.spec import board_from_dict

    return board_from_dict({"type": "chessboard", "squares": [11, 8], "square": 4.77})


def _views(n, seed):
    import cv2

    from pencilcal.toolkit.board.synthetic import synthetic_detections
    from pencilcal.toolkit.synth.chessboard import render_chessboard

    cam, board = bench_camera(), bench_board()
    poses = synthetic_detections(cam, board, views=n, noise_px=0.0, seed=seed, tilt_deg=50.0, margin_px=12.0).truth
    rng = np.random.default_rng(seed)
    bufs = []
    for rvec, tvec in poses:
        img = render_chessboard(cam, cv2.Rodrigues(np.asarray(rvec, float))[0], tvec, board, rng, noise=3.0,
                                blur_px=1.0)
        bufs.append(cv2.imencode(".png", img)[1])
    return cam, board, bufs


def bench_calibrate(n=50, seed=0):
    """The calibration figures (the module's docstring); times in seconds."""
    import cv2

    from pencilcal.toolkit.board.calibrate import calibrate
    from pencilcal.toolkit.board.detect import detect_board
    from pencilcal.validation.calibration_run import calibrate_checked

    cam, board, bufs = _views(n, seed)
    size = cam.size
    t0 = time.perf_counter()
    dets = [detect_board(cv2.imdecode(b, cv2.IMREAD_GRAYSCALE), board) for b in bufs]
    t_detect = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = calibrate_checked(dets, board, size)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    calibrate(dets, board, size, warp=True, corner_noise=True)
    t_fit = time.perf_counter() - t0
    obj = board.object_points()
    found = [d for d in dets if d.count]
    o = [obj[d.ids].astype(np.float32).reshape(-1, 1, 3) for d in found]
    p = [d.corners.astype(np.float32).reshape(-1, 1, 2) for d in found]
    t0 = time.perf_counter()
    cv2.calibrateCamera(o, p, size, None, None)
    t_cv = time.perf_counter() - t0
    return {"calibrate_vs_opencv_960x540": float((t_detect + t_ours) / (t_detect + t_cv)),
            "calibrate_fit_vs_opencv": float(t_fit / t_cv), "calibrate_detect_s": float(t_detect),
            "calibrate_s": float(t_ours), "calibrate_checks_s": float(t_ours - t_fit),
            "opencv_calibrate_s": float(t_cv), "calibrate_views_found": f"{len(found)}/{n}",
            "calibrate_fx_error": float(res.camera.fx - cam.fx),
            "calibrate_verdict": res.checks.verdict.status}
