"""The typed results of a reconstruction: `SfmFrame` per input frame (its `to_dict` is the
frame record of the sfm poses.json) and `SfmResult` (its `summary` the file's other keys).

Poses are ``R_cam_from_world``, ``t_cam_from_world`` (p_cam = R p_world + t, OpenCV camera
frame) in the reconstruction's own world frame and arbitrary scale.

Example
-------
>>> import numpy as np
>>> f = SfmFrame("000.png", 0, True, np.eye(3), np.zeros(3), np.zeros(3), "000.png", 812, 240)
>>> d = f.to_dict()
>>> d["registered"], d["t_cam_from_world"], d["num_features"]
(True, [0.0, 0.0, 0.0], 812)
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pencilcal.toolkit.camera.formats import camera_to_dict
from pencilcal.toolkit.camera.model import Camera

__all__ = ["STAGES", "SfmFrame", "SfmResult"]

#: Stages reported to the progress callback, in order, and timed in `SfmResult.timings`.
STAGES = ("prepare", "extract", "match", "map", "write")


@dataclass
class SfmFrame:
    """One input frame's result.

    Attributes
    ----------
    image : str
        The input frame's name (file name, or frame_000123 for a video frame).
    index : int
        Position in the input sequence.
    registered : bool
        True when the kept model holds a pose for this frame.
    R_cam_from_world : (3, 3) ndarray or None
        Rotation world -> camera (OpenCV camera frame).
    t_cam_from_world : (3,) ndarray or None
        Translation, in the reconstruction's arbitrary length unit.
    camera_center : (3,) ndarray or None
        Camera centre in the world frame, ``-R^T t``.
    colmap_name : str or None
        The image's name in the COLMAP database and model (None when never given to COLMAP).
    num_features : int
        SIFT features extracted (0 when not extracted).
    num_points3D : int
        Features of this frame that are observations of a 3D point of the kept model.
    error : str or None
        Why the frame has no pose (undecodable, too few features, not registered).
    """

    image: str
    index: int
    registered: bool = False
    R_cam_from_world: np.ndarray | None = None
    t_cam_from_world: np.ndarray | None = None
    camera_center: np.ndarray | None = None
    colmap_name: str | None = None
    num_features: int = 0
    num_points3D: int = 0
    error: str | None = None

    def to_dict(self):
        """The frame's record in poses.json (JSON-ready: arrays as nested lists)."""
        return {
            "image": self.image,
            "index": self.index,
            "registered": bool(self.registered),
            "error": self.error,
            "R_cam_from_world": None if self.R_cam_from_world is None else self.R_cam_from_world.tolist(),
            "t_cam_from_world": None if self.t_cam_from_world is None else self.t_cam_from_world.tolist(),
            "camera_center": None if self.camera_center is None else self.camera_center.tolist(),
            "colmap_name": self.colmap_name,
            "num_features": int(self.num_features),
            "num_points3D": int(self.num_points3D),
        }


@dataclass
class SfmResult:
    """What `reconstruct` found.

    Attributes
    ----------
    frames : list of SfmFrame
        One per input frame, in input order.
    camera : Camera
        The camera the reconstruction used (the input; unchanged).
    n_registered, n_points3D : int
        Registered frames and 3D points of the kept model.
    mean_reprojection_error_px : float
        COLMAP's mean reprojection error over the kept model's observations [px].
    matching : str
        "exhaustive" or "sequential" (what "auto" chose).
    max_features : int
    n_models : int
        Models mapping produced; the largest is kept (``sparse/0``).
    model_sizes : list of int
        Registered frames per model, largest first.
    workdir, model_path, database_path : Path
        ``workdir``, ``workdir/sparse/0`` and ``workdir/database.db``.
    image_path : str or None
        The folder COLMAP read the images from (None once a staged folder is removed).
    timings : dict
        Seconds per stage (`STAGES`) and ``total``.
    camera_unchanged : bool
        The model's camera parameters are bit-identical to the input (always true for a
        returned result: anything else raises).
    pycolmap_version : str
    warnings : list of str
        One-line warnings (several models, frames not registered or undecodable).
    reconstruction : pycolmap.Reconstruction or None
        The kept model in memory (not written to poses.json).
    """

    frames: list
    camera: Camera
    n_registered: int
    n_points3D: int
    mean_reprojection_error_px: float
    matching: str
    max_features: int
    n_models: int
    model_sizes: list
    workdir: Path
    model_path: Path
    database_path: Path
    image_path: str | None
    timings: dict
    camera_unchanged: bool
    pycolmap_version: str
    warnings: list = field(default_factory=list)
    reconstruction: object = None

    @property
    def n_frames(self):
        """Input frames (registered or not)."""
        return len(self.frames)

    @property
    def registered(self):
        """(N,) bool: which frames have a pose."""
        return np.array([f.registered for f in self.frames], bool)

    def frame(self, image):
        """The SfmFrame of the input frame named `image` (KeyError if none)."""
        for f in self.frames:
            if f.image == image:
                return f
        raise KeyError(image)

    def rotations(self):
        """(names, R_cam_from_world (K, 3, 3)) over the registered frames, in input order."""
        reg = [f for f in self.frames if f.registered]
        R = np.array([f.R_cam_from_world for f in reg]).reshape(-1, 3, 3)
        return [f.image for f in reg], R

    def summary(self, relative_to=None):
        """The summary keys of poses.json (paths relative to `relative_to` when given)."""
        def rel(p):
            if p is None:
                return None
            if relative_to is None:
                return str(p)
            try:
                return os.path.relpath(p, relative_to)
            except ValueError:  # another drive (Windows)
                return str(p)

        image_path = self.image_path
        if image_path is not None and relative_to is not None and Path(image_path).is_relative_to(self.workdir):
            image_path = rel(image_path)
        return {
            "frames_count": self.n_frames,
            "registered_count": self.n_registered,
            "points3D_count": self.n_points3D,
            "mean_reprojection_error_px": self.mean_reprojection_error_px,
            "matching": self.matching,
            "max_features": self.max_features,
            "models_count": self.n_models,
            "model_sizes": list(self.model_sizes),
            "model": rel(self.model_path),
            "database": rel(self.database_path),
            "image_path": image_path,
            "camera": camera_to_dict(self.camera),
            "camera_unchanged": bool(self.camera_unchanged),
            "timings_s": dict(self.timings),
            "pycolmap_version": self.pycolmap_version,
            "warnings": list(self.warnings),
        }
