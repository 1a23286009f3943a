"""Geometry shared by everything: angle wrapping, rotations and frames, the pencil as a 1-D projective map."""
