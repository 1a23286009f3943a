"""validation.radial_run: one radial frame as `orient IMAGES` measures it, with tracking."""
import numpy as np

from pencilcal.toolkit.pencil.orientation import Orientation
from pencilcal.validation import radial_run


class _Found:
    def to_dict(self):
        return {"segments": np.zeros((0, 4))}


def test_a_final_labelling_refused_after_orient_kept_it_is_not_tracked_from(monkeypatch):
    """`orient` stores an ok record as the tracker's previous frame; where the final labelling
    is then refused (`trimmed_at_spokes_end`), the next frame must not track from it."""
    from pencilcal.toolkit.detect import lines, radial

    kept = Orientation(image="f.png", ok=True)

    def orient(pencil, fr, keep):
        return kept

    def trimmed(detect, oriented, camera, pencil, img, joint, gamma):
        rec = oriented(_Found())  # what the command's orient stores as previous
        assert rec.ok
        return _Found(), Orientation(image="f.png", ok=False, error="ambiguous labelling")

    def tracking_orient(pencil, fr, keep):
        rec = orient(pencil, fr, keep)
        state["previous"] = rec if rec.ok else None
        return rec

    monkeypatch.setattr(radial, "trimmed_at_spokes_end", trimmed)
    monkeypatch.setattr(lines, "detect_frame_lines", lambda *a, **k: _Found())
    state = {"previous": None, "tracked": 0}
    fr, rec = radial_run.radial_frame("f.png", np.zeros((8, 8), np.uint8), None, None, "auto",
                                      {"radial_joint": "auto"}, tracking_orient, state)
    assert not rec.ok
    assert state["previous"] is None
