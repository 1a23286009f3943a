"""Regenerate the binary part of the bad-input corpus (images, video) from exact renders.

Run from the repository root: python tests/corpus/make_corpus.py. The text files beside it
(cameras, boards, pencils, lines) are written by hand; cases.yaml says what each case must
produce. Inputs too large to keep in the repository (100k segments, a 14 MB lines.json,
clutter) or one per numeric field (NaN, inf, strings) are made by the `GENERATORS` below
when a case runs (its ``generate:`` key); ``python tests/corpus/make_corpus.py --big DIR``
writes them all to DIR for use by hand.
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np

from pencilcal.toolkit.board.spec import write_board
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.pencil.spec import write_pencil
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.synth.render import render_frame
from pencilcal.toolkit.synth.scenarios import make_scenario

HERE = Path(__file__).resolve().parent


def main():
    sc = make_scenario("tilt-sweep", frames=4, seed=7, size=(320, 180), max_tilt_deg=40.0)
    write_camera(HERE / "camera.json", sc.camera, force=True)
    write_board(HERE / "board.yaml", sc.sheet.board, force=True)
    write_pencil(HERE / "pencil_fan.yaml", sc.sheet.pencil, force=True)
    good = HERE / "frames"
    good.mkdir(exist_ok=True)
    imgs = [sc.render(i) for i in range(4)]
    for i, im in enumerate(imgs):
        cv2.imwrite(str(good / f"{i:03d}.png"), im)
    # a truncated and a zero-byte image among good ones
    data = (good / "001.png").read_bytes()
    (good / "002_truncated.png").write_bytes(data[: len(data) // 3])
    (good / "003_empty.png").write_bytes(b"")
    (good / "002.png").unlink()
    (good / "003.png").unlink()
    # images of another size than the camera
    small = HERE / "wrong_size"
    small.mkdir(exist_ok=True)
    cv2.imwrite(str(small / "000.png"), cv2.resize(imgs[0], (160, 90)))
    # a video with corrupt frames: MJPG frames with bytes overwritten in the middle ones
    path = HERE / "corrupt.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (320, 180))
    for k in range(8):
        im = imgs[k % 4]
        vw.write(im if im.ndim == 3 else cv2.cvtColor(im, cv2.COLOR_GRAY2BGR))
    vw.release()
    raw = bytearray(path.read_bytes())
    soi = [i for i in range(len(raw) - 1) if raw[i] == 0xFF and raw[i + 1] == 0xD8]
    for s in soi[3:5]:  # two frames' JPEG data destroyed
        raw[s : s + 400] = b"\x00" * 400
    path.write_bytes(bytes(raw))
    # the board seen edge-on (89 deg): nothing to detect
    sheet = sc.sheet
    R = rotation_about_axis([1.0, 0, 0], np.radians(89.0))
    edge = HERE / "edge_on"
    edge.mkdir(exist_ok=True)
    cv2.imwrite(str(edge / "000.png"), render_frame(sc.camera, R, np.array([-100.0, 0.0, 300.0]), sheet, rng=1))
    (HERE / "empty_folder").mkdir(exist_ok=True)
    (HERE / "empty_folder" / ".keep").write_text("an input folder with no images in it\n")
    print("corpus written to", HERE)


# ---------------------------------------------------------------- generated inputs

SMALL = (320, 180)  # camera_pinhole.json
FRONTAL = json.loads((HERE / "lines_frontal.json").read_text())["frames"][0]["segments"]


def _fan_segments(seed):
    """The 8 spokes of pencil.yaml (0-140 deg, no radius) tilted 35 deg in camera_pinhole.json
    (320x180), 0.3 px of end point noise: (8, 4) raw px."""
    from pencilcal.toolkit.camera.formats import read_camera
    from pencilcal.toolkit.pencil.spec import project_spokes, read_pencil

    cam, pen = read_camera(HERE / "camera_pinhole.json"), read_pencil(HERE / "pencil.yaml")
    rng = np.random.default_rng(seed)
    R = rotation_about_axis([0.0, 0, 1], rng.uniform(0, 6.28)) @ rotation_about_axis([1.0, 0, 0], np.radians(35.0))
    seg = project_spokes(cam, R.T, np.array([0.0, 0.0, 60.0]), pen, (5.0, 30.0))
    return seg + 0.3 * rng.normal(size=seg.shape)


def _clutter(k, seed, size=SMALL, length=(5.0, 100.0)):
    rng = np.random.default_rng(seed)
    c = rng.uniform([0, 0], size, (k, 2))
    a = rng.uniform(0, np.pi, k)
    d = np.stack([np.cos(a), np.sin(a)], -1) * rng.uniform(*length, k)[:, None] / 2
    return np.c_[c - d, c + d]


def _write_lines(path, frames):
    Path(path).write_text(json.dumps({"frames": frames}, allow_nan=True))


def clutter_lines(path, k=1000, frames=2):
    """A clean frame (the fan alone) and `frames` frames of the fan among k random segments."""
    out = [{"image": "clean.png", "segments": _fan_segments(0).tolist()}]
    for i in range(frames):
        seg = np.r_[_fan_segments(i + 1), _clutter(k, i + 1)]
        out.append({"image": f"clutter_{i}.png", "segments": seg[np.random.default_rng(i).permutation(len(seg))].tolist()})
    _write_lines(path, out)


def many_segments(path, k=100_000):
    """A clean frame (the fan alone) and one of the fan among k random segments (a detector
    gone wild, or an attacker)."""
    _write_lines(path, [{"image": "clean.png", "segments": _fan_segments(0).tolist()},
                        {"image": "many.png", "segments": np.r_[_fan_segments(5), _clutter(k, 5)].round(3).tolist()}])


def huge_lines(path):
    """A 14 MB lines.json (well within files.MAX_INPUT_BYTES): 400k segments in one frame."""
    many_segments(path, 400_000)


def bad_frame_field(path, key, value):
    """The frontal frame with one per-segment field (or `segments` itself) given `value`
    for every segment (a string, NaN, inf...)."""
    fr = {"image": "bad.png", "segments": FRONTAL}
    if key == "segments":
        fr["segments"] = [FRONTAL[0][:3] + [value]] + FRONTAL[1:]
    else:
        fr[key] = [value] * len(FRONTAL)
    _write_lines(path, [fr])


def bad_shaft_field(path, key, value):
    """A pivot-like frame whose one shaft has `key` set to `value` (midline: its last
    coordinate)."""
    shaft = {"midline": [100.0, 20.0, 160.0, 170.0], "width_px": 20.0, "angle_sigma_deg": 0.2,
             "offset_sigma_px": 0.3, "edges": [[90.0, 20.0, 150.0, 170.0], [110.0, 20.0, 170.0, 170.0]],
             "convergence_deg": 0.5, "score": 3.0}
    if key in ("midline", "edges"):
        shaft[key] = shaft["midline"][:3] + [value] if key == "midline" else [shaft["edges"][0][:3] + [value]]
    else:
        shaft[key] = value
    _write_lines(path, [{"image": "bad.png", "segments": [], "shafts": [shaft]}])


def bad_pencil(path, key, value):
    """pencil_fan.yaml with one field set to `value` (angles_deg: its last angle)."""
    import yaml

    d = yaml.safe_load((HERE / "pencil_fan.yaml").read_text())
    if key == "angles_deg":
        d[key] = d[key][:-1] + [value]
    elif key in ("vertex", "radius"):
        d[key] = [d[key][0], value]
    elif key in ("start_deg", "step_deg", "count"):
        d = {"start_deg": 0, "step_deg": 20, "count": 8, key: value}
    else:
        d[key] = value
    Path(path).write_text(yaml.safe_dump(d, sort_keys=False))


# ---------------------------------------------------------------- whole-system faults (issue 27)
# inputs of the cases run as the installed command in a subprocess (`process: true`)


def many_frames(folder, n):
    """A folder of `n` copies of frames/000.png: a run long enough to be interrupted."""
    import shutil

    folder = Path(folder)
    folder.mkdir()
    for i in range(int(n)):
        shutil.copyfile(HERE / "frames" / "000.png", folder / f"{i:03d}.png")


def hostile_folder(folder):
    """Two good frames among entries that cannot be read: a symlink in a loop, a symlink to
    nothing, and a frame whose name is not UTF-8 (the byte 0xE9, Latin-1's e-acute)."""
    import shutil

    folder = Path(folder)
    folder.mkdir()
    for name in ("000.png", "001.png"):
        shutil.copyfile(HERE / "frames" / name, folder / name)
    os.symlink("loop.png", folder / "loop.png")
    os.symlink("nowhere.png", folder / "dangling.png")
    shutil.copyfile(HERE / "frames" / "000.png", os.fsencode(folder) + b"/caf\xe9.png")


def unreadable_folder(folder):
    """Two good frames and one the user running pencilcal may not read (mode 000)."""
    hostile = Path(folder)
    many_frames(hostile, 2)
    (hostile / "002_secret.png").write_bytes((HERE / "frames" / "000.png").read_bytes())
    os.chmod(hostile / "002_secret.png", 0)


def locked_folder(folder):
    """A folder of two good frames that the user running pencilcal may not list (mode 000)."""
    many_frames(folder, 2)
    os.chmod(folder, 0)


def locked_file(path, name):
    """A copy of the corpus file `name` that the user running pencilcal may not read."""
    Path(path).write_bytes((HERE / name).read_bytes())
    os.chmod(path, 0)


def latin1_file(path):
    """A camera file in Latin-1, not UTF-8: a key with an e-acute."""
    Path(path).write_bytes(b'{"\xe9": 1}')


def odd_entries_folder(folder):
    """frames/000.png beside a pipe named as an image (a read would wait for ever) and a 3 GB
    image file (a hole on the disk: past 16 bytes a pixel of --max-pixels)."""
    folder = Path(folder)
    many_frames(folder, 1)
    os.mkfifo(folder / "pipe.png")
    sparse_file(folder / "huge.png", 3 * 2**30)


def symlink_loop(path):
    """IMAGES that is a symlink to itself."""
    os.symlink(Path(path).name, path)


def video(path, frames, keep=1.0):
    """An MJPEG AVI (or an MP4) of `frames` frames, the corpus' good frames over and over,
    cut to its first `keep` fraction of bytes (a recording cut short)."""
    good = [cv2.imread(str(HERE / "frames" / n)) for n in ("000.png", "001.png")]
    fourcc = "mp4v" if str(path).endswith(".mp4") else "MJPG"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, (320, 180))
    for k in range(int(frames)):
        vw.write(good[k % 2])
    vw.release()
    data = Path(path).read_bytes()
    Path(path).write_bytes(data[: int(len(data) * float(keep))])


def camera_with(path, entry, value):
    """camera_pinhole.json with one entry of K (fx, fy, cx, cy) set to `value`."""
    d = json.loads((HERE / "camera_pinhole.json").read_text())
    i, j = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[entry]
    d["K"][i][j] = float(value)
    Path(path).write_text(json.dumps(d))


def tiny_image(path, width, height):
    """A `width` x `height` grey image, and a camera of that size beside it (NAME.json)."""
    cv2.imwrite(str(path), np.full((int(height), int(width)), 128, np.uint8))
    cam = {"model": "pinhole", "width": int(width), "height": int(height),
           "K": [[300.0, 0, width / 2], [0, 300.0, height / 2], [0, 0, 1]], "dist": []}
    Path(path).with_suffix(".json").write_text(json.dumps(cam))


def pixel_bomb(folder, width, height):
    """frames/000.png and a PNG of a few hundred bytes whose header claims width x height."""
    import shutil
    import zlib

    folder = Path(folder)
    folder.mkdir()
    shutil.copyfile(HERE / "frames" / "000.png", folder / "000.png")

    def chunk(kind, data):
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    ihdr = int(width).to_bytes(4, "big") + int(height).to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    (folder / "001_bomb.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) +
                                          chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))


def sparse_file(path, size):
    """A file of `size` bytes that takes no room on the disk (a hole): a camera file past
    files.MAX_INPUT_BYTES without writing one."""
    with open(path, "wb") as f:
        f.truncate(int(size))


def huge_validation(path):
    """A validation.json whose first frame's tilt is 1e308 (the report's figures overflowed
    on it)."""
    frame = {"image": "000.png", "ok": True, "tilt_deg": 1e308}
    Path(path).write_text(json.dumps({"frames": [frame], "summary": {}, "pencil": {"angles_deg": [0, 20, 40]}}))


def blank_frames(folder, n):
    """`n` plain grey 320x180 frames: neither a board nor a pencil to find."""
    folder = Path(folder)
    folder.mkdir()
    for i in range(int(n)):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.full((180, 320), 128, np.uint8))


GENERATORS = {f.__name__: f for f in (clutter_lines, many_segments, huge_lines, bad_frame_field, bad_shaft_field,
                                      bad_pencil, many_frames, hostile_folder, unreadable_folder, locked_folder,
                                      locked_file, latin1_file, odd_entries_folder, symlink_loop, video, camera_with, tiny_image,
                                      pixel_bomb, sparse_file, blank_frames, huge_validation)}


def generate(spec, folder):
    """Make a case's generated inputs: spec {file name: [generator, *args]} -> the paths."""
    out = {}
    for name, (gen, *args) in spec.items():
        out[name] = Path(folder) / name
        GENERATORS[gen](out[name], *args)
    return out


if __name__ == "__main__":
    if sys.argv[1:2] == ["--big"]:
        import yaml

        folder = Path(sys.argv[2])
        folder.mkdir(parents=True, exist_ok=True)
        for case in yaml.safe_load((HERE / "cases.yaml").read_text()):
            # an input several cases share is made once
            todo = {n: g for n, g in case.get("generate", {}).items() if not os.path.lexists(folder / n)}
            for name, path in generate(todo, folder).items():
                print(case["name"], "->", path)
    else:
        main()
