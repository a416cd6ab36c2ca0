"""Running a job: plan, one picklable job per frame, helper processes, resume, batch over scenes.

``annotate_rgbd.pipeline.run_cvat2mask`` is the documented entry (loaded on first use).
"""

from __future__ import annotations


def __getattr__(name: str):
    if name == "run_cvat2mask":
        from annotate_rgbd.pipeline.scene import run_cvat2mask

        return run_cvat2mask
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
