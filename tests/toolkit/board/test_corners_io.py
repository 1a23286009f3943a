"""mrcal corner cache (corners.vnl): format details, round trip, errors."""
from __future__ import annotations


import numpy as np
import pytest

from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.board.corners_cache import LEGEND, corners_vnl_text, read_corners_vnl, write_corners_vnl
from pencilcal.toolkit.board.detect import BoardDetection
from pencilcal.toolkit.errors import InputError

CHARUCO = board_from_dict({"type": "charuco", "squares": [5, 4], "square": 30.0, "marker": 22.0,
                           "dictionary": "DICT_4X4_50"})  # 4 x 3 inner corners
CHESS = board_from_dict({"type": "chessboard", "squares": [4, 3], "square": 25.0})


def det(ids, xy, size=(640, 480)):
    return BoardDetection(np.asarray(ids, int), np.asarray(xy, float).reshape(-1, 2), size, np.zeros(0, int),
                          np.zeros((0, 4, 2)))


def data_rows(text):
    return [ln.split() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]


def test_format_matches_mrcal_conventions():
    rng = np.random.default_rng(0)
    ids = np.array([0, 1, 2, 3, 5, 6, 7, 11])  # a partial ChArUco view
    xy = rng.uniform(0, 600, (ids.size, 2))
    text = corners_vnl_text([("img0.png", det(ids, xy)), ("img1.png", None),
                             ("img2.png", det([], np.zeros((0, 2))))], CHARUCO)
    lines = text.splitlines()
    # the vnlog legend is the first line; other '#' lines are '##' comments
    assert lines[0] == LEGEND == "# filename x y level"
    assert all(ln.startswith("##") for ln in lines[1:] if ln.startswith("#"))
    assert "--object-width-n 4 --object-height-n 3 --object-spacing 30" in text
    rows = data_rows(text)
    # a detected image has exactly width_n * height_n rows in row-major grid order
    img0 = [r for r in rows if r[0] == "img0.png"]
    assert len(img0) == 12
    for k, r in enumerate(img0):
        if k in ids:
            j = int(np.flatnonzero(ids == k)[0])
            assert float(r[1]) == xy[j, 0] and float(r[2]) == xy[j, 1] and r[3] == "0"
        else:
            assert r[1:] == ["-", "-", "-"]
    # no detection (None or empty): one 'filename - - -' row
    assert [r for r in rows if r[0] == "img1.png"] == [["img1.png", "-", "-", "-"]]
    assert [r for r in rows if r[0] == "img2.png"] == [["img2.png", "-", "-", "-"]]
    # every row has 4 whitespace-separated fields, and images are contiguous
    assert all(len(r) == 4 for r in rows)
    assert [r[0] for r in rows] == ["img0.png"] * 12 + ["img1.png", "img2.png"]


def test_chessboard_grid_is_row_major_over_columns():
    # corner id k of a (cols=4, rows=3) chessboard is row k // 4, column k % 4
    xy = np.array([[100.0 + 10 * (k % 4), 50.0 + 10 * (k // 4)] for k in range(12)])
    rows = data_rows(corners_vnl_text([("a.png", det(np.arange(12), xy))], CHESS))
    assert [(float(r[1]), float(r[2])) for r in rows[:5]] == [(100, 50), (110, 50), (120, 50), (130, 50), (100, 60)]


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(1)
    recs = []
    for i in range(5):
        ids = np.sort(rng.choice(12, size=rng.integers(4, 13), replace=False))
        recs.append((f"frame_{i:03d}.png", det(ids, rng.uniform(-0.4, 1279.4, (ids.size, 2)))))
    recs.insert(2, ("empty.png", None))
    path = tmp_path / "corners.vnl"
    write_corners_vnl(path, recs, CHARUCO)
    back = read_corners_vnl(path, CHARUCO, image_size=(640, 480))
    assert [n for n, _ in back] == [n for n, _ in recs]
    for (_, a), (_, b) in zip(recs, back):
        if a is None:
            assert b is None
            continue
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.corners, b.corners)  # bit for bit
        assert b.image_size == (640, 480)


def test_reads_mrgingham_output_and_weights(tmp_path):
    p = tmp_path / "c.vnl"
    # mrgingham without a level column; and a 'weight' legend (--corners-cache-has-weights)
    rows = "\n".join(f"a.jpg {k}.5 {k}.25" for k in range(12))
    p.write_text("# filename x y\n" + rows + "\nb.jpg - -\n")
    out = read_corners_vnl(p, CHESS)
    assert out[0][1].count == 12 and out[1] == ("b.jpg", None)
    rows = "\n".join(f"a.jpg {k} {k} {0.0 if k == 3 else 1.0}" for k in range(12))
    p.write_text("# filename x y weight\n" + rows + "\n")
    assert 3 not in read_corners_vnl(p, CHESS)[0][1].ids
    # a level of '-' or < 0 marks a missing corner (mrcal)
    rows = "\n".join(f"a.jpg {k} {k} {-1 if k == 4 else ('-' if k == 5 else 1)}" for k in range(12))
    p.write_text("## comment before the legend\n# filename x y level\n" + rows + "\n")
    ids = read_corners_vnl(p, CHESS)[0][1].ids.tolist()
    assert 4 not in ids and 5 not in ids and len(ids) == 10


@pytest.mark.parametrize("content,match", [
    ("a.png 1 2 0\n", "data before the legend"),
    ("# file x y\n", "legend must be"),
    ("# filename x y level\n" + "a.png 1 2 0\n" * 5, "has 5 rows; the 4 x 3 grid needs 12"),
    ("# filename x y level\na.png 1 2 0\n", "has 1 row"),
    ("# filename x y level\na.png 1 2\n", "expected 4 fields"),
    ("# filename x y level\n" + "a.png x 2 0\n" * 12, "must be numbers"),
    ("# filename x y level\na.png - - -\nb.png - - -\na.png - - -\n", "not contiguous"),
    ("## only comments\n", "no legend"),
])
def test_read_errors(tmp_path, content, match):
    p = tmp_path / "c.vnl"
    p.write_text(content)
    with pytest.raises(InputError, match=match):
        read_corners_vnl(p, CHESS)


def test_write_errors_and_no_clobber(tmp_path):
    d = det(np.arange(12), np.arange(24.0))
    p = tmp_path / "c.vnl"
    with pytest.raises(InputError, match="cannot be written to a vnlog"):
        write_corners_vnl(p, [("my image.png", d)], CHESS)
    with pytest.raises(InputError, match="appears twice"):
        write_corners_vnl(p, [("a.png", d), ("a.png", None)], CHESS)
    with pytest.raises(InputError, match="corner ids outside"):
        write_corners_vnl(p, [("a.png", det(np.arange(12), np.arange(24.0)))], board_from_dict(
            {"type": "chessboard", "squares": [3, 3], "square": 1.0}))
    assert not p.exists()  # nothing half-written
    write_corners_vnl(p, [("a.png", d)], CHESS)
    before = p.read_text()
    with pytest.raises(InputError, match="already exists"):
        write_corners_vnl(p, [("b.png", None)], CHESS)
    assert p.read_text() == before
    write_corners_vnl(p, [("b.png", None)], CHESS, force=True)
    assert read_corners_vnl(p, CHESS) == [("b.png", None)]
    assert sorted(f.name for f in tmp_path.iterdir()) == ["c.vnl"]  # no temporary files left
