"""validation.report.sections: the sensitivity plan next to what was measured, and its file."""
from __future__ import annotations

import json

import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import to_jsonable
from pencilcal.validation import report as rp
from pencilcal.validation.report.sections import sensitivity_section
from tests.validation.report.helpers import assert_self_contained, decoded_images, synthetic


def test_sensitivity_block(tmp_path):
    from pencilcal.validation.sensitivity import Setup, plan

    sens = json.loads(json.dumps(to_jsonable(
        plan(Setup(), tilts_deg="0:60:15", offaxis_deg="0,20", trials=20, accuracy_deg=0.5, seed=1,
             backend="numpy"))))
    data = synthetic(tmp_path, n=3, failing=False)
    page = rp.render_html(rp.build_report(data, samples=0, sensitivity=sens))
    assert_self_contained(page)
    assert sens["answer"]["text"].split(",")[0] in page
    i = page.index('id="sensitivity"')
    assert len(decoded_images(page[i:])) == 2  # the tilt x off-axis map and planned vs measured
    assert "could not be drawn" not in page
    # a bound-only plan (no Monte Carlo) renders too
    sens0 = json.loads(json.dumps(to_jsonable(plan(Setup(), tilts_deg="0:60:15", offaxis_deg="0", trials=0,
                                                   backend="numpy"))))
    sec = sensitivity_section(data, sens0)
    assert sum(isinstance(b, rp.Plot) for b in sec.blocks) == 2
    assert "Cramer-Rao bound" in sec.blocks[0].text
    assert not [b for b in sec.blocks if isinstance(b, rp.Para) and "could not be drawn" in b.text]


def test_load_sensitivity_names_the_file(tmp_path):
    sens = tmp_path / "s.json"
    sens.write_text(json.dumps({"answer": {}}))
    with pytest.raises(InputError, match="not a sensitivity file"):
        rp.load_sensitivity(sens)
