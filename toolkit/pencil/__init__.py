"""Pencils of lines: the pencil file, the exact estimator (numpy, scalar and torch), spoke assignment, the vertex, orientation, the fulcrum, and the book chapter's models."""
