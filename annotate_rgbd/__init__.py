"""annotate-rgbd: CVAT plane polygons on RGB-D sequences -> depth-verified plane instance masks."""

__version__ = "0.1.0"
