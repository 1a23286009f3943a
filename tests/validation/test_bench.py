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
