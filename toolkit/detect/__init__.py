"""Line features in images: line segments, printed bars and instrument shafts, with subpixel edges and honest uncertainties."""
