"""Running a job: plan, one picklable job per frame, helper processes, resume, batch over scenes.

``annotate_rgbd.pipeline.run_cvat2mask`` is the documented entry (loaded on first use).
"""

from __future__ import annotations


def __getattr__(name: str):
    if name in ("run_cvat2mask", "finish_scene"):
        from annotate_rgbd.pipeline import scene

        return getattr(scene, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
