"""The format-neutral annotation model, annotation parts, stitching parts into global planes, and
the mapping of depth frames to annotated RGB frames."""
