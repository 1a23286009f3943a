"""Files and images: atomic writing and safe reading of structured files (`files`), image
sources and the one image decoder (`images`), the lines file (`lines_file`), frames in
worker processes (`parallel`)."""

from __future__ import annotations

from pencilcal.toolkit.io.files import atomic_write, atomic_path, atomic_folder, write_json, load_structured
from pencilcal.toolkit.io.images import open_images, decode_image, Frame
from pencilcal.toolkit.io.lines_file import LineFrame, read_lines, write_lines
from pencilcal.toolkit.io.parallel import map_frames

__all__ = ["atomic_write", "atomic_path", "atomic_folder", "write_json", "load_structured", "open_images",
           "decode_image", "Frame", "LineFrame", "read_lines", "write_lines", "map_frames"]
