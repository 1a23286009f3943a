"""Camera intrinsics: projection and undistortion, and the camera file formats of OpenCV, mrcal and COLMAP."""
