"""Files and images: atomic writing, structured files, image sources, the lines file, frames in parallel."""
