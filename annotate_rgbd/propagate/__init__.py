"""Pose-guided propagation: keyframe shapes lifted onto their planes and carried to every frame."""
