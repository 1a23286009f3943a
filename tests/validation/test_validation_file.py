"""validation_file: the validation.json written and read back, and one-line errors that name
the file for everything that is not one."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.validation.validation_file import (
    check_validation,
    load_pencil_validation,
    load_validation,
    write_validation,
)


def _minimal():
    return {"frames": [{"image": "a.png", "ok": True, "R_ref": np.eye(3), "reference_tilt_deg": np.float64(12.5)}],
            "summary": {"orient:exact": {"frames": 1, "normal": {"median": float("nan")}}},
            "pencil": {"angles_deg": [0.0, 20.0, 40.0]}}


def test_written_file_reads_back_as_json(tmp_path):
    p = tmp_path / "validation.json"
    write_validation(p, _minimal())
    data = load_validation(p)
    assert data["frames"][0]["R_ref"] == np.eye(3).tolist()
    assert data["frames"][0]["reference_tilt_deg"] == 12.5
    assert data["summary"]["orient:exact"]["normal"]["median"] is None  # NaN is null in JSON
    assert load_pencil_validation(p) == data
    with pytest.raises(InputError, match="already exists"):
        write_validation(p, _minimal())
    write_validation(p, {"frames": [], "summary": {}}, force=True)
    assert load_validation(p) == {"frames": [], "summary": {}}


def test_check_names_the_part_that_is_wrong():
    with pytest.raises(InputError, match=r"^v\.json: frame 1 is not an object$"):
        check_validation({"frames": [{}, 3], "summary": {}}, "v.json")
    with pytest.raises(InputError, match=r"^v\.json: summary\['sfm'\] is not an object$"):
        check_validation({"frames": [], "summary": {"sfm": []}}, "v.json")
    d = {"frames": [], "summary": {}}
    assert check_validation(d) is d


def test_pencil_reader_needs_spoke_angles_not_a_summary(tmp_path):
    p = tmp_path / "v.json"
    p.write_text(json.dumps({"frames": [], "pencil": {"angles_deg": [0, 20, 40]}}))
    assert load_pencil_validation(p)["pencil"]["angles_deg"] == [0, 20, 40]
    with pytest.raises(InputError, match="not a validation file"):
        load_validation(p)  # the report needs the summary
    p.write_text(json.dumps({"frames": [], "pencil": {"angles_deg": [0, 20]}}))
    with pytest.raises(InputError, match="at least three 'angles_deg'"):
        load_pencil_validation(p)
    p.write_text(json.dumps({"frames": [], "pencil": {"angles_deg": [0, "a", 40]}}))
    with pytest.raises(InputError, match="must be numbers"):
        load_pencil_validation(p)


def test_load_validation_errors_name_the_file(tmp_path):
    bad = tmp_path / "v.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match=r"v\.json: not valid JSON"):
        load_validation(bad)
    bad.write_text(json.dumps({"frames": []}))
    with pytest.raises(InputError, match=r"v\.json: not a validation file"):
        load_validation(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(InputError, match="not a validation file"):
        load_validation(bad)
    with pytest.raises(InputError, match="not found"):
        load_validation(tmp_path / "missing.json")
    with pytest.raises(InputError, match="is a folder"):
        load_validation(tmp_path)
