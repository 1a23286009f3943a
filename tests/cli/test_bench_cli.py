"""`pencilcal bench`: the figures exist and are sane (no timing is asserted: ratios vary)."""
from __future__ import annotations

import json

from click.testing import CliRunner

from pencilcal.cli.main import cli


def test_bench_json_keys(tmp_path):
    r = CliRunner().invoke(cli, ["bench", "--json", "--quick", "--sections", "orient,pnp,estimator", "-q",
                                 "-o", str(tmp_path / "b.json")])
    assert r.exit_code == 0, r.output
    res = json.loads(r.output)
    for key in ("orient_vs_fld_1080p", "pnp_vs_opencv", "batch_speedup", "fits_per_minute_batched", "crlb_ratio_tilt20"):
        assert isinstance(res[key], float) and res[key] > 0, key
    # the Monte Carlo part is an accuracy figure, not a timing: it must be near 1
    assert 0.8 < res["crlb_ratio_tilt20"] < 1.25
    assert json.loads((tmp_path / "b.json").read_text())["crlb_ratio_tilt20"] == res["crlb_ratio_tilt20"]


def test_bench_bad_section():
    r = CliRunner().invoke(cli, ["bench", "--sections", "gpu"])
    assert r.exit_code == 2
