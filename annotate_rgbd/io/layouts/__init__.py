"""RGB-D sequence layouts on disk, each read in one place into one format-neutral model.

:func:`~annotate_rgbd.io.sequence.read_sequence` recognises the layout of a folder by the files it
holds and hands it to that layout's reader, which fills in a
:class:`~annotate_rgbd.io.layouts.model.Sequence`: its colour and depth frame lists, what its
timestamps count (seconds or frame numbers), and what the layout itself states: a depth camera, a
colour camera on another grid, per-frame poses. One module per family of layouts:

- :mod:`~annotate_rgbd.io.layouts.tum`: TUM RGB-D (``rgb.txt``, ``depth.txt``), ICL-NUIM in TUM
  format (``associations.txt``), ``rgb/`` and ``depth/`` folders named by timestamps, and the
  depth-only forms (``depth.txt`` or ``depth/`` alone) that ``propose`` reads;
- :mod:`~annotate_rgbd.io.layouts.scannet`: ScanNet's export (``color/``, ``depth/``, ``pose/``,
  ``intrinsic/``);
- :mod:`~annotate_rgbd.io.layouts.seven_scenes`: 7-Scenes (``frame-000000.color.png``,
  ``.depth.png``, ``.pose.txt``);
- :mod:`~annotate_rgbd.io.layouts.lists`: what they share (lists, numbered files, matrices, bounds);
- :mod:`~annotate_rgbd.io.layouts.model`: the model.

:func:`annotate_rgbd.io.sequence.read_sequence` tries the layouts in the order of its ``LAYOUTS``;
the first that fits reads the folder. This package imports nothing itself, so that the model is
light to import (the trajectory readers need only it and :mod:`~annotate_rgbd.io.layouts.lists`).
"""
