"""Instrument mask files (MASKS): one segmentation mask per frame, paired with IMAGES.

A lab's segmentation network writes one mask image per frame: binary (any non-zero value is
instrument), a label image (each value a class or a part), an instance image (one value per
instrument) or a colour mask. `mask_files` lists them (a folder, a glob pattern, files: as
IMAGES are listed, `images.open_images`), `pair_masks` pairs them with the frames: by file
stem (frame ``frame007.jpg`` with mask ``frame007.png``), else,
when there are as many masks as frames, in order; anything else is an InputError naming
what is unmatched. `read_mask` decodes one as stored (8 or 16 bit, grey or colour: OpenCV's
IMREAD_UNCHANGED, alpha dropped) and checks its size against the frame's.

Example
-------
>>> pair_masks(["a.png", "b.png"], ["masks/b.png", "masks/a.png"])
{'a.png': 'masks/a.png', 'b.png': 'masks/b.png'}
>>> pair_masks(["f1.jpg", "f2.jpg"], ["m/x1.png", "m/x2.png"])          # no stems in common: in order
{'f1.jpg': 'm/x1.png', 'f2.jpg': 'm/x2.png'}
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = ["mask_files", "pair_masks", "read_mask", "parse_mask_label", "InstrumentMasks", "source_masks"]


def mask_files(spec):
    """The mask files of MASKS: one or more image files, folders (their images, sorted
    naturally) or glob patterns, in the order given (list of str)."""
    from pencilcal.toolkit.io.images import open_images

    try:
        src = open_images(spec)
    except InputError as e:
        raise InputError(f"instrument masks: {e}") from None
    if src.kind != "images":
        raise InputError(f"{src.description}: instrument masks must be image files, not a video")
    return [str(p) for p in src.paths]


def _listed(names, more=3):
    shown = ", ".join(names[:more])
    return shown + (f" (and {len(names) - more} more)" if len(names) > more else "")


def pair_masks(frame_names, masks, where="MASKS"):
    """{frame name: mask path} for every frame.

    frame_names: the frames' names (`images.Frame.name`: file names, or frame_000123 for a
    video); masks: the mask files (`mask_files`). By stem when every frame has a mask of its
    stem (one mask per stem), else in order when the counts match; else InputError naming
    the unmatched frames (where: the MASKS as given, for the message).
    """
    names = [str(n) for n in frame_names]
    by_stem = {}
    for m in masks:
        by_stem.setdefault(Path(m).stem, []).append(m)
    twice = sorted(s for s, v in by_stem.items() if len(v) > 1)
    stems = [Path(n).stem for n in names]
    if not twice and all(s in by_stem for s in stems):
        return {n: by_stem[s][0] for n, s in zip(names, stems)}
    if len(masks) == len(names):
        return dict(zip(names, masks))
    missing = [n for n, s in zip(names, stems) if s not in by_stem]
    if twice:
        raise InputError(f"{where}: several masks named {twice[0]} (the masks are paired with the frames by file "
                         "name)")
    raise InputError(f"{where}: {len(masks)} mask(s) for {len(names)} frame(s), and no mask named as "
                     f"{_listed(missing)} (masks are paired with frames by file name, or in order when as many)")


def read_mask(path, shape):
    """The mask image at path as stored ((H, W) or (H, W, 3), any depth), its size checked
    against the frame's shape (H, W); InputError naming the file otherwise."""
    import cv2

    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        raise InputError(f"{path}: cannot read the mask: {e.strerror}") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise InputError(f"{path}: cannot decode the mask (not an image, or corrupt)")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    if tuple(img.shape[:2]) != tuple(shape[:2]):
        raise InputError(f"{path}: the mask is {img.shape[1]}x{img.shape[0]} but its frame is {shape[1]}x{shape[0]}")
    return img


def parse_mask_label(text):
    """A mask label as given on the command line: an integer (a label image's value) or
    B,G,R (a colour mask's colour); InputError otherwise.

    >>> parse_mask_label("10"), parse_mask_label("0,255,0")
    (10, (0, 255, 0))
    """
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        vals = None
    if vals is None or len(vals) not in (1, 3) or any(v < 0 for v in vals):
        raise InputError(f"mask label {text!r}: expected a non-negative integer or B,G,R")
    return vals[0] if len(vals) == 1 else tuple(vals)


class InstrumentMasks:
    """The instrument masks of a sequence's frames (`source_masks`): `paths` (frame name ->
    mask file), `labels` (the values or colours that are instrument, or None: every non-zero
    one) and `instances` (each value one instrument); `of(frame)` reads a decoded frame's
    (`images.Frame`) as `detect.lines.shaft_records` takes it. Plain data: it travels to
    worker processes."""

    def __init__(self, paths, labels=None, instances=False):
        self.paths = dict(paths)
        self.labels = labels
        self.instances = bool(instances)

    def of(self, frame):
        """``{"mask", "labels", "instances"}`` of one decoded frame (InputError naming the
        frame or the mask file where it has none or it does not fit)."""
        if frame.name not in self.paths:
            raise InputError(f"{frame.name}: no instrument mask paired with this frame")
        return {"mask": read_mask(self.paths[frame.name], frame.image.shape), "labels": self.labels,
                "instances": self.instances}


def source_masks(source, spec, labels=(), instances=False):
    """The `InstrumentMasks` of MASKS (spec: `mask_files`) for the frames of an image
    source (`images.ImageSource`; a video's frames are frame_000000, ...): paired by
    `pair_masks`; labels: integers or B,G,R, as values or as text (`parse_mask_label`),
    all of one kind."""
    parsed = [parse_mask_label(v) if isinstance(v, str) else v for v in labels or ()]
    if len({isinstance(v, tuple) for v in parsed}) > 1:
        raise InputError("mask labels: all integers or all B,G,R colours")
    names = ([f"frame_{i:06d}" for i in range(source.count)] if source.kind == "video"
             else [p.name for p in source.paths])
    return InstrumentMasks(pair_masks(names, mask_files(spec), where=str(spec)), parsed or None, instances)
