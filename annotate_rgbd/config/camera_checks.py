"""What a configuration file's ``[camera]`` table says that is likely a mistake."""

from __future__ import annotations

from typing import Any

from annotate_rgbd.geometry.camera import Camera

#: The intrinsics a ``[camera]`` table gives together (``depth_scale`` alone is a common change).
INTRINSICS = ("fx", "fy", "cx", "cy")


def partial_intrinsics(table: Any, defaults: Camera) -> str | None:
    """Why a ``[camera]`` table looks half-written: it gives some of the intrinsics
    (:data:`INTRINSICS`) but not all, so the others would be the defaults', another camera's.

    Parameters
    ----------
    table : Any
        The file's ``[camera]`` table as read from TOML (anything else: None is returned).
    defaults : Camera
        What the missing intrinsics would be.

    Returns
    -------
    str or None
        A one-line warning; None when the table gives all or none of the intrinsics.
    """
    if not isinstance(table, dict):
        return None
    given = [key for key in INTRINSICS if key in table]
    missing = [key for key in INTRINSICS if key not in table]
    if not given or not missing:
        return None
    used = ", ".join(f"{key} = {getattr(defaults, key):g}" for key in missing)
    verb = "is" if len(missing) == 1 else "are"
    return (f"[camera] gives {', '.join(given)} but not {', '.join(missing)}: the default {used} {verb} used "
            "(the ROS default of a Kinect v1 at 640x480); give all four intrinsics of your camera")
