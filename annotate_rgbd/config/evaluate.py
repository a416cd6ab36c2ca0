"""The ``[evaluate]`` section: the IoU thresholds of ``annotate-rgbd evaluate``, with their source."""

from __future__ import annotations

from dataclasses import dataclass

from .rules import check_section


@dataclass(frozen=True)
class EvaluateConfig:
    """The ``[evaluate]`` section: when two planes match in the EVOPS metrics
    (:func:`annotate_rgbd.evaluate.metrics.frame_statistics`).

    Parameters
    ----------
    full : float
        IoU at which a predicted and a ground-truth plane are the same plane (a true positive;
        ``--full``). 0.75: ``evops.metrics.constants.IOU_THRESHOLD_FULL`` of the ``evops`` 1.0.0
        package (the EVOPS paper itself used 0.8 on synthetic and 0.5 on real data).
    partial : float
        IoU at which they overlap partially (for usr, osr, noise, missed; ``--partial``). 0.2:
        ``evops.metrics.constants.IOU_THRESHOLD_PART`` of ``evops`` 1.0.0.
    ignore : int
        Label value of the ground truth's "don't care" pixels (``--ignore``): they are left out of
        both the ground truth and the prediction before scoring. -1: none (every label a plane,
        as in EVOPS's own ground truth). Ground truth made by ray-casting a fused mesh marks
        plane borders and ambiguous depth so: 65535 in the real-data kit of issue 26 (and 255
        in many 8-bit segmentation sets).
    """

    full: float = 0.75
    partial: float = 0.2
    ignore: int = -1

    def __post_init__(self):
        check_section("evaluate", self, [
            ("full", lambda v: 0 < v <= 1, "must be in (0, 1]"),
            ("partial", lambda v: 0 < v <= 1, "must be in (0, 1]"),
            ("ignore", lambda v: v >= -1, "must be a label value >= 0, or -1 for none"),
        ])
