"""Pose-guided propagation: keyframe shapes lifted onto their planes and carried to every frame."""

#: Where the keyframes before and after a frame agree less than this about a carried plane
#: there (:func:`annotate_rgbd.propagate.carry.keyframe_agreement`: they share less of what both
#: saw of the plane than they disagree on, about: the agreement counts a few pixels more as
#: agreeing), every keyframe's outline counts over what the nearer ones excluded
#: (:func:`annotate_rgbd.propagate.carry.carried_layers`), and ``stats`` lists the plane to check.
#: On TUM fr1_rpy at a keyframe every 10th frame (docs/propagation.md) 12 % of the carried planes
#: fall below it; carried with every outline there, the run's mean IoU rose at every keyframe
#: spacing (0.916 -> 0.926 at every 10th frame), and 0.3 or 0.7 measured within 0.004 of 0.5
#: (docs/benchmarks.md). Here, not in ``carry``: ``stats`` loads no image library.
DISAGREE_BELOW = 0.5
