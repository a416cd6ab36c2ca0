"""Plane proposals: the labeller corrects outlines instead of drawing them.

``annotate-rgbd propose`` detects planes on the depth frames with no annotation given and writes
them as a "CVAT for video 1.1" export of polygon tracks, colour masks and a report. One job per
module:

- :mod:`~annotate_rgbd.propose.detect_job`: one frame (detection with
  :func:`annotate_rgbd.detect.detect_planes`, merging of coplanar pieces, polygons in draw
  order (:mod:`annotate_rgbd.cvat.from_masks`), the drop rules of
  :mod:`annotate_rgbd.segment.filters`), run in helper processes;
- :mod:`~annotate_rgbd.propose.measures`: what a plane's polygon fills and covers;
- :mod:`~annotate_rgbd.propose.link`: detections -> tracks (with or without poses);
- :mod:`~annotate_rgbd.propose.output`: polygon tracks as CVAT XML, colour masks;
- :mod:`~annotate_rgbd.propose.run`: :func:`run_propose`, the whole sequence.

The tunables, with their defaults and sources, are the ``[detect]``, ``[propose]`` and ``[link]``
sections of the configuration (:mod:`annotate_rgbd.config.propose`).
"""

from .detect_job import FrameProposal, propose_planes
from .link import TrackLinker, link_proposals
from .run import ProposeResult, run_propose

__all__ = ["FrameProposal", "ProposeResult", "TrackLinker", "link_proposals", "propose_planes", "run_propose"]
