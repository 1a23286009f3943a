"""The benchmarks' helpers run (the figures themselves are `pencilcal bench`'s)."""
from __future__ import annotations

import pytest

from pencilcal.toolkit.pencil.torch_backend import torch_available
from pencilcal.validation.bench import benchmark_batched

needs_torch = pytest.mark.skipif(not torch_available(), reason='torch/kornia not installed (pip install -e ".[torch]")')


@needs_torch
def test_benchmark_runs():
    r = benchmark_batched(n=600, loop_n=3, numpy_batched_n=300, dtypes=("float64",))
    assert r["torch_float64_fits_per_s"] > 0 and r["numpy_loop_fits_per_s"] > 0
    assert r["max_rotation_diff_deg_float64_vs_numpy"] < 1e-6


def test_shafts_bench_runs():
    """One frame: the shared real frames when present, else a rendered one; it says which."""
    from pencilcal.validation.bench import bench_shafts

    r = bench_shafts(n=1, repeats=1)
    assert r["shafts_vs_fld_1080p"] > 0 and r["shafts_frames"].split()[0] in ("laparoscopy-hysterectomy-frames", "rendered")


def test_calibrate_bench_runs():
    """A dozen rendered views: pencilcal's calibration finds the lens (fx within a pixel) and
    the ratio and its parts are there."""
    from pencilcal.validation.bench_calibrate import bench_calibrate

    r = bench_calibrate(n=12)
    assert r["calibrate_vs_opencv_960x540"] > 0 and r["calibrate_fit_vs_opencv"] > 0
    assert r["calibrate_views_found"] == "12/12" and abs(r["calibrate_fx_error"]) < 1.0
    assert r["calibrate_verdict"] in ("usable", "usable within this region", "not usable")
def test_motion_benches_run_and_report_tracking():
    """The moving-camera benchmarks on a few frames: every figure there, the fan's tilts
    against the truth, the instrument's tracking counted."""
    from pencilcal.validation.bench_video import bench_orient_motion, bench_shafts_motion, handheld_frames

    cam, pencil, slow, tilt, fast, tilt2 = handheld_frames(4, size=(640, 360))
    assert len(slow) == len(fast) == 4 and slow[0].shape == (360, 640)
    assert tilt2[1] == pytest.approx(tilt[2]) and tilt2[0] == pytest.approx(tilt[0])  # twice as fast, the same path
    r = bench_orient_motion(frames=6, repeats=1)
    assert r["orient_motion_frames"] == r["orient_motion2x_frames"] == 6
    for key in ("orient_motion", "orient_motion_overlay", "orient_motion_overlay_full", "orient_motion2x_overlay"):
        assert r[f"{key}_vs_decode_fld_1080p"] > 0 and r[f"{key}_cpu_vs_decode_fld"] > 0
    assert r["orient_motion_tilt_within_0p5"] == 1.0 and r["orient_motion2x_frames_lost"] == 0
    assert 0.5 <= r["orient_motion_tracked"] <= 1.0
    s = bench_shafts_motion(frames=6, repeats=1)
    assert s["shafts_motion_vs_decode_fld_1080p"] > 0 and 0.5 <= s["shafts_motion_tracked"] <= 1.0
    assert s["shafts_motion_lines_vs_decode_fld_1080p"] > 0 and 0.5 <= s["shafts_motion_lines_tracked"] <= 1.0
