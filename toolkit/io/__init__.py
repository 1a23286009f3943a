"""Files and images: atomic writing and safe reading of structured files (`files`), image
sources and the one image decoder (`images`), the lines file (`lines_file`), frames in
worker processes (`parallel`)."""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "files": ["atomic_write", "atomic_path", "atomic_folder", "write_json", "load_structured"],
    "images": ["open_images", "decode_image", "Frame"],
    "lines_file": ["LineFrame", "read_lines", "write_lines"],
    "parallel": ["map_frames"],
})


__all__ = ["atomic_write", "atomic_path", "atomic_folder", "write_json", "load_structured", "open_images",
           "decode_image", "Frame", "LineFrame", "read_lines", "write_lines", "map_frames"]
