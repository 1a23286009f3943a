"""The masked real sources of ../shared/data/real-instruments (SOURCE.txt there), as the shaft
score reads them: per source its frames, their masks and how a mask names its instruments.

Each entry: name -> (folder, image glob, mask glob, labels, instances), read from
tests/data/masked_sources.json. The images and masks
are paired in sorted order. Used by the shaft score tests and the leave-one-source-out table
(tests/validation/test_shaft_protocol.py, docs/method.md).
"""
from __future__ import annotations

import json
from pathlib import Path

#: The sources file (`validation.shaft_training.read_sources`: the shipped pixel model is
#: trained on the same sources).
SOURCES_FILE = Path(__file__).resolve().parents[1] / "data" / "masked_sources.json"
SOURCES = {name: (s["folder"], s["images"], s["masks"],
                  None if s["labels"] is None else [tuple(v) if isinstance(v, list) else v for v in s["labels"]],
                  bool(s["instances"])) for name, s in json.loads(SOURCES_FILE.read_text()).items()}


def load_source(name):
    """(frames, region) of one source: frames a list of (image path, BGR image, references
    (MaskAxis per instrument), instrument masks); the valid region detected from its frames."""
    import cv2
    import numpy as np

    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from pencilcal.toolkit.detect.shaft.mask import instruments_in_mask, mask_axis
    from pencilcal.toolkit.detect.shaft.work import axis_matrix
    from tests.conftest import data_dir

    folder, image_glob, mask_glob, labels, instances = SOURCES[name]
    root = data_dir("real-instruments") / folder
    paths, mask_paths = sorted(root.glob(image_glob)), sorted(root.glob(mask_glob))
    assert paths and len(paths) == len(mask_paths), f"{name}: {len(paths)} frames, {len(mask_paths)} masks"
    images = [cv2.imread(str(p)) for p in paths]
    region = detect_valid_region(images)
    frames = []
    for path, mpath, img in zip(paths, mask_paths, images):
        insts = instruments_in_mask(cv2.imread(str(mpath), cv2.IMREAD_UNCHANGED), labels, instances)
        valid = region.mask(img.shape[:2])
        K = axis_matrix(None, img.shape[:2])[0]
        frames.append((path, img, [mask_axis(m, valid, K) for m in insts], insts))
    return frames, region
