"""A scenario written to disk as `pencilcal simulate` writes it: the one writer of a
simulated sequence folder.

Layout of the folder::

    images/000.png ...     the rendered frames
    camera.json, camera.yaml   the intrinsics (pencilcal and OpenCV formats)
    board.yaml, pencil.yaml    the printed sheet's board and fan
    angles.csv             pivot scenario only: image,angle_deg
    truth.json             per frame R_cam_from_target, t_cam_from_target, normal, vertex_px, ...

The folder is built beside its target and put in place whole (io.files.atomic_folder): a
failed or interrupted run leaves no partial folder and keeps an earlier one.

Example
-------
>>> import tempfile, os
>>> from pencilcal.toolkit.synth.scenarios import make_scenario
>>> out = os.path.join(tempfile.mkdtemp(), "sim")
>>> write_sequence(out, make_scenario("tilt-sweep", 2, 0, size=(160, 90)))
>>> sorted(os.listdir(out)), sorted(os.listdir(os.path.join(out, "images")))
(['board.yaml', 'camera.json', 'camera.yaml', 'images', 'pencil.yaml', 'truth.json'], ['000.png', '001.png'])
"""
from __future__ import annotations

import os
from pathlib import Path

from pencilcal.toolkit.errors import InputError

__all__ = ["write_sequence", "check_sequence_output", "looks_like_sequence"]


def looks_like_sequence(path) -> bool:
    """True for an empty folder or one a simulated sequence was written to (safe to replace)."""
    entries = set(os.listdir(path))
    return not entries or "truth.json" in entries


def check_sequence_output(out, force=False):
    """InputError before any work if the folder `out` cannot (or must not) be written: its
    parent is missing, it is a file, or it holds anything but an earlier sequence (that
    one only with `force`)."""
    from pencilcal.toolkit.io.files import check_folder_writable

    out = Path(out)
    check_folder_writable(out)
    if out.exists() or out.is_symlink():
        if not out.is_dir() or out.is_symlink():
            raise InputError(f"{out}: exists and is not a folder")
        entries = os.listdir(out)
        if entries and not force:
            raise InputError(f"{out}: folder is not empty; pass --force to replace an earlier simulate output")
        if entries and not looks_like_sequence(out):
            raise InputError(f"{out}: folder is not empty and holds no truth.json; not replacing it, even with --force")


def write_sequence(out, scenario, *, noise=None, blur_px=None, lighting=None, gamma=None, color=False,
                   background="table", camera_source=None, progress=None):
    """Render every frame of `scenario` and write the sequence folder `out` (module doc).

    noise, blur_px, lighting, gamma: rendering settings (None: the scenario's defaults,
    scenarios.RENDER_DEFAULTS); color: BGR frames instead of grey; background: "table"
    (textured, for SfM), "plain" or "tissue" (`tissue.tissue_image`, the sheet not drawn);
    camera_source: what truth.json says the camera came
    from; progress: a wrapper for the frame loop (e.g. a progress bar), given
    ``range(len(scenario))``.
    """
    import cv2

    from pencilcal.toolkit.board.spec import write_board
    from pencilcal.toolkit.camera.formats import write_camera
    from pencilcal.toolkit.io.files import atomic_folder, atomic_write, write_json
    from pencilcal.toolkit.pencil.spec import write_pencil
    from pencilcal.toolkit.synth.scenarios import RENDER_DEFAULTS

    given = {"noise": noise, "blur_px": blur_px, "lighting": lighting, "gamma": gamma}
    settings = {k: (RENDER_DEFAULTS[k] if v is None and k in RENDER_DEFAULTS else v) for k, v in given.items()}
    settings = {k: v for k, v in settings.items() if v is not None}
    bg = {"table": None, "tissue": "tissue"}.get(background, "plain")
    frames = range(len(scenario))
    with atomic_folder(out) as tmp:
        (tmp / "images").mkdir()
        for i in (progress(frames) if progress else frames):
            img = scenario.render(i, color=color, background=bg, **settings)
            path = tmp / "images" / scenario.frames[i]["image"]
            ok, buf = cv2.imencode(path.suffix, img)
            if not ok:
                raise InputError(f"{path}: cannot encode the image")
            path.write_bytes(buf.tobytes())  # an OSError (a full disk) names the output folder: atomic_folder
        write_camera(tmp / "camera.json", scenario.camera)
        write_camera(tmp / "camera.yaml", scenario.camera)
        write_board(tmp / "board.yaml", scenario.sheet.board)
        write_pencil(tmp / "pencil.yaml", scenario.sheet.pencil)
        csv = scenario.angles_csv()
        if csv is not None:
            atomic_write(tmp / "angles.csv", csv)
        render = dict(settings, color=color, background=background,
                      camera=camera_source or f"built-in {scenario.camera.model}")
        write_json(tmp / "truth.json", scenario.truth(render=render))
