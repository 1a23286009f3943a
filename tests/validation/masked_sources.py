"""The masked real sources of ../shared/data/real-instruments (SOURCE.txt there), as the shaft
score reads them: per source its frames, their masks and how a mask names its instruments.

Each entry: name -> (folder, image glob, mask glob, labels, instances). The images and masks
are paired in sorted order. Used by the shaft score tests and the leave-one-source-out table
(tests/validation/test_shaft_protocol.py, docs/method.md).
"""
from __future__ import annotations

SOURCES = {
    # two dVRK instruments over a suturing pad; BGR (0, 255, 0) instrument, (0, 255, 255) needle
    "dvrk-suturing": ("dvrk-suturing-masks", "image_*_img.png", "image_*_label.png", [(0, 255, 0)], False),
    # a box trainer with two laparoscopic instruments (255 = instrument)
    "box-trainer": ("box-trainer-and-greenscreen", "box_trainer.jpg", "box_trainer_mask.png", None, False),
    # one EndoWrist instrument over a green screen (255 = instrument)
    "greenscreen": ("box-trainer-and-greenscreen", "greenscreen.png", "greenscreen_mask.png", None, False),
    # human cholecystectomy, 854x480, circular field; one id per instrument
    "cholec": ("cholec-instance-masks", "frames/*.png", "masks_inst/*.png", None, True),
    # da Vinci Xi, 1920x1080 letterboxed; 255 = any instrument part (masks_parts/ tells shaft 10, wrist 20, claspers 30)
    "endovis17": ("endovis17-seq4-masks", "frames/*.png", "masks/*.png", None, False),
}
