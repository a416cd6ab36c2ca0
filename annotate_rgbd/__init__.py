"""annotate-rgbd: CVAT plane polygons on RGB-D sequences -> depth-verified plane instance masks.

Every command is a function (the names below load on first use, so ``import annotate_rgbd``
stays light)::

    from annotate_rgbd import load_config, run_cvat2mask
    result = run_cvat2mask("seq", ["annotations.xml"], "out", load_config("fr1_desk"))
    print(result.written, result.counts, result.warnings)

``run_cvat2mask`` / ``run_batch`` (masks), ``run_propose`` (proposals), ``review_run`` (overlays
and the review page), ``export_cvat`` (a run as a CVAT export), ``evaluate_paths`` (EVOPS
metrics), ``load_config`` / ``Config`` (settings), the result record ``SceneResult``, and the
two error types every command raises with a one-line message: ``InputError``, ``OutputError``.
"""

from __future__ import annotations

from importlib import import_module

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_EXPORTS = {
    "run_cvat2mask": "annotate_rgbd.pipeline.scene",
    "run_batch": "annotate_rgbd.pipeline.batch",
    "SceneResult": "annotate_rgbd.pipeline.execute",
    "run_propose": "annotate_rgbd.propose.run",
    "review_run": "annotate_rgbd.review.review",
    "export_cvat": "annotate_rgbd.export.cvat",
    "evaluate_paths": "annotate_rgbd.evaluate.evaluate",
    "load_config": "annotate_rgbd.config.settings",
    "Config": "annotate_rgbd.config.settings",
    "InputError": "annotate_rgbd.errors",
    "OutputError": "annotate_rgbd.errors",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value  # loaded once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
