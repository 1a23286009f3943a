"""Regenerate the binary part of the bad-input corpus (images, video) from exact renders.

Run from the repository root: python tests/corpus/make_corpus.py. The text files beside it
(cameras, boards, pencils, lines) are written by hand; cases.yaml says what each case must
produce.
"""
from __future__ import annotations

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


if __name__ == "__main__":
    main()
