"""The frames of a reconstruction: decoded once, checked against the camera, and given to
COLMAP by name from one image folder (step 1 of `reconstruct`).

Files COLMAP reads itself (`options.COLMAP_READS`) are read in place; video frames and other
formats are written as PNG under ``workdir/images``. COLMAP names images by their path
relative to one image folder, so files from several folders, duplicate names, or (for
sequential matching, which pairs images in *byte* order of their names) names whose byte
order is not the frame order are linked into ``workdir/images`` under names prefixed
with the frame index. Each frame keeps its input name.

Example
-------
>>> import numpy as np, tempfile
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("pinhole", 64, 48, [[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
>>> img = np.zeros((48, 64, 3), np.uint8)
>>> items, folder, names, mode, staged = prepare_frames([img, img, img], cam, tempfile.mkdtemp(), "auto", 3, None)
>>> names, mode, staged
(['000000.png', '000001.png', '000002.png'], 'exhaustive', True)
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.images import IMAGE_EXTENSIONS, Frame, ImageSource, check_image_size, open_images

from .options import COLMAP_READS, choose_matching

__all__ = ["prepare_frames"]


@dataclass
class _Item:
    """One input frame on its way to COLMAP."""

    name: str                 # the input frame's name
    index: int
    source: str | None        # a file COLMAP can read in place, else None
    error: str | None = None  # undecodable
    colmap_name: str | None = None
    num_features: int = 0


def _frames_of(images):
    """Iterate (Frame) over any accepted input; also say whether it is a video."""
    if isinstance(images, ImageSource):
        return iter(images), images.count, images.kind == "video", images.description
    if isinstance(images, (str, os.PathLike)):
        src = open_images(images)
        return iter(src), src.count, src.kind == "video", src.description
    items = list(images)

    def gen():
        for i, it in enumerate(items):
            if isinstance(it, Frame):
                yield Frame(it.name, i, it.image, it.error, it.path)
            elif isinstance(it, np.ndarray):
                yield Frame(f"{i:06d}", i, it, None, None)
            elif isinstance(it, (str, os.PathLike)):
                p = Path(it)
                if not p.is_file():
                    raise InputError(f"{p}: no such image file")
                fr = next(iter(ImageSource(p)))
                yield Frame(fr.name, i, fr.image, fr.error, fr.path)
            else:
                raise InputError(f"frame {i}: expected an image array, a Frame or a path, got {type(it).__name__}")

    return gen(), len(items), False, f"{len(items)} frames"


def _png_name(name):
    """A decoded frame's file name: its name with .png for its image extension, if any."""
    p = Path(name)
    return (p.stem if p.suffix.lower() in IMAGE_EXTENSIONS else name) + ".png"


def prepare_frames(images, camera, workdir, matching, min_registered, progress):
    """Check every frame and decide what COLMAP reads.

    images, camera, matching, min_registered, progress: as `reconstruct`. Returns (items,
    image_path, names, mode, staged): one item per input frame (``name``, ``index``,
    ``error`` for an undecodable one, ``colmap_name``, ``num_features``), the folder COLMAP
    reads, the names it reads there in frame order, the matching mode, and whether
    image_path is the folder made here (``workdir/images``), never the input's own folder.
    """
    import cv2

    it, count, is_video, desc = _frames_of(images)
    stage_dir = Path(workdir) / "images"
    staged = []

    def stage():
        # never write into a folder that was there before (it may hold the input images)
        if not staged:
            stage_dir.parent.mkdir(parents=True, exist_ok=True)
            try:
                stage_dir.mkdir()
            except FileExistsError:
                raise InputError(f"{stage_dir}: exists; give reconstruct an empty work folder") from None
            staged.append(stage_dir)
        return stage_dir

    items, decoded = [], {}
    for fr in it:
        if progress is not None:
            progress("prepare", fr.index + 1, max(count, fr.index + 1))
        if fr.image is None:
            items.append(_Item(fr.name, len(items), None, fr.error or "cannot decode the image"))
            continue
        check_image_size(fr, camera)
        direct = (not is_video and fr.path is not None and Path(fr.path).suffix.lower() in COLMAP_READS
                  and Path(fr.path).is_file())
        item = _Item(fr.name, len(items), str(Path(fr.path).resolve()) if direct else None)
        if not direct:
            # written now as PNG (fast compression: a scratch copy), so no frame stays in memory
            img = fr.image
            if img.dtype not in (np.uint8, np.uint16):
                raise InputError(f"{fr.name}: image type {img.dtype} is neither 8 nor 16 bit")
            tmp = stage() / f".frame{item.index:09d}.png"
            if not cv2.imwrite(str(tmp), img, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
                raise InputError(f"{tmp}: cannot write a decoded frame")
            decoded[item.index] = tmp
        items.append(item)
    good = [x for x in items if x.error is None]
    need = max(2, min_registered)
    if len(good) < need:
        got = f"{len(good)} decodable image{'s' if len(good) != 1 else ''}" + \
            (f" of {len(items)}" if len(items) != len(good) else "")
        raise InputError(f"{desc}: structure from motion needs at least {need} images "
                         f"(--min-registered {min_registered}); got {got}")
    mode = choose_matching(matching, len(good))

    # the input names when they are unique, sort in frame order (sequential matching pairs
    # images in byte order of their names) and, for files read in place, share one folder
    plain = [Path(x.source).name if x.source else _png_name(x.name) for x in good]
    unique = len(set(plain)) == len(plain)
    ordered = mode != "sequential" or plain == sorted(plain)
    folders = {str(Path(x.source).parent) for x in good if x.source}
    if not decoded and unique and ordered and len(folders) == 1:
        for x, n in zip(good, plain):
            x.colmap_name = n
        return items, folders.pop(), [x.colmap_name for x in good], mode, False
    width = max(6, len(str(len(items))))
    folder = stage()
    for x, n in zip(good, plain):
        x.colmap_name = n if unique and ordered else f"{x.index:0{width}d}_{n}"
        dst = folder / x.colmap_name
        if x.source is not None:
            try:
                os.symlink(x.source, dst)
            except OSError:  # no symlinks on this filesystem: copy
                shutil.copyfile(x.source, dst)
        else:
            os.replace(decoded[x.index], dst)
    return items, str(folder), [x.colmap_name for x in good], mode, True
