"""pencilcal.toolkit: camera models and file formats, the geometry of pencils, estimators,
line and board detection, and rendering of synthetic scenes."""
