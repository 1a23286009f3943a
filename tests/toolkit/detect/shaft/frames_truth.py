"""The hand-made list of what each unmasked real frame shows (tests/data/real_frames_truth.yaml).

The file's header says how it was made and what each field means; in short, per set (a folder
of ../shared/data/real-instruments) and frame file name:

- ``instruments``: a list of dicts with ``axis`` (float array, shape (4,): x1, y1, x2, y2 in the
  frame's pixels, (0, 0) the centre of the top-left pixel, proximal end first), ``width_px``
  (float), ``kind`` ("shaft" or "part"), ``visible`` (str) and ``uncertain`` (bool, False when
  the file leaves it out);
- ``notes``: str, what else in the frame could fool a detector.

>>> truth = load_real_frames_truth()
>>> sorted(truth)
['dvrk-lnd-phantom-sequence', 'laparoscopy-hysterectomy-frames']
>>> first = truth["dvrk-lnd-phantom-sequence"]["1.png"]["instruments"][0]
>>> first["axis"].shape, first["kind"], first["uncertain"]
((4,), 'shaft', False)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

TRUTH_PATH = Path(__file__).resolve().parents[3] / "data" / "real_frames_truth.yaml"
SETS = ("laparoscopy-hysterectomy-frames", "dvrk-lnd-phantom-sequence")
KINDS = ("shaft", "part")
INSTRUMENT_KEYS = {"axis", "width_px", "kind", "visible", "uncertain"}


def _instrument(raw, where: str) -> dict:
    if not isinstance(raw, dict) or not {"axis", "width_px", "kind", "visible"} <= set(raw) \
            or not set(raw) <= INSTRUMENT_KEYS:
        raise ValueError(f"{TRUTH_PATH}: {where}: an instrument needs exactly the keys "
                         f"axis, width_px, kind, visible (and optionally uncertain), got {raw!r}")
    return {
        "axis": np.asarray(raw["axis"], dtype=float),
        "width_px": float(raw["width_px"]),
        "kind": raw["kind"],
        "visible": raw["visible"],
        "uncertain": raw.get("uncertain", False),
    }


def load_real_frames_truth(path: Path | str = TRUTH_PATH) -> dict:
    """{set name: {frame file name: {"instruments": [...], "notes": str}}} from the YAML file.

    Axes come back as float arrays of shape (4,); the values are as written (the structure test,
    test_frames_truth.py, checks their types and ranges). A frame entry without the two keys,
    or an instrument with missing or unknown keys, raises ValueError naming the file.
    """
    path = Path(path)
    raw = yaml.safe_load(path.read_text())
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: expected a mapping of image sets, got {type(raw).__name__}")
    out = {}
    for set_name, frames in raw.items():
        if not isinstance(frames, dict):
            raise ValueError(f"{path}: {set_name}: expected a mapping of frame file names")
        out[set_name] = {}
        for frame, entry in frames.items():
            where = f"{set_name}/{frame}"
            if not isinstance(entry, dict) or set(entry) != {"instruments", "notes"}:
                raise ValueError(f"{path}: {where}: expected exactly the keys instruments and notes")
            if not isinstance(entry["instruments"], list):
                raise ValueError(f"{path}: {where}: instruments must be a list")
            out[set_name][frame] = {
                "instruments": [_instrument(i, where) for i in entry["instruments"]],
                "notes": entry["notes"],
            }
    return out
