"""pencilcal.toolkit: camera models and file formats, the geometry of pencils, estimators,
line and board detection, and rendering of synthetic scenes."""
import os as _os

# COLMAP (through pycolmap) logs with glog, which holds INFO lines of its log file in a
# buffer for up to 30 s. pencilcal follows COLMAP's progress in that file
# (validation/sfm.py), so it asks glog to write each line through. glog reads this once,
# when pycolmap is loaded; a value the user set is kept.
_os.environ.setdefault("GLOG_logbuflevel", "-1")
