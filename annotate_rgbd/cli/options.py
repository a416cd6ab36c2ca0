"""Checks of option values that click's own types and ranges cannot state, run as the command
line is parsed: a value out of range is a usage error (status 2) naming the option, as for every
other option. Each check is the library's own rule where there is one."""

from __future__ import annotations

from typing import Optional

import typer


def share_of_image(value: Optional[float]) -> Optional[float]:
    """``--min-area``: a share of the image in (0, 1] (NaN passes a range check of its own)."""
    if value is not None and not 0 < value <= 1:
        raise typer.BadParameter(f"must be a share of the image in (0, 1], not {value:g}")
    return value


def seconds(value: float) -> float:
    """``--job-timeout``: seconds, ``inf`` to wait for ever (the option's range lets NaN through,
    which would never take a hung helper for hung)."""
    if not value >= 1:
        raise typer.BadParameter(f"must be a number of seconds >= 1 (inf: wait for ever), not {value:g}")
    return value


def polygon_budget(param: typer.CallbackParam, value: Optional[float]) -> Optional[float]:
    """``export-cvat --tolerance`` (the option's range lets NaN and infinity through) and
    ``--max-vertices`` (0 or at least 3), as :func:`annotate_rgbd.export.cvat.export_cvat` takes them."""
    if value is not None:
        from annotate_rgbd.export.cvat import tolerance_problem, vertex_budget_problem

        problem = (tolerance_problem if param.name == "tolerance" else vertex_budget_problem)(value)
        if problem:
            raise typer.BadParameter(problem)
    return value


#: Options of ``cvat2mask`` that set one configuration key each (over ``--config``): option -> key.
OPTION_SETTINGS = {
    "distance_threshold": "ransac.distance_threshold",
    "max_invalid_ratio": "filter.max_invalid_ratio",
    "max_mean_distance": "filter.max_mean_distance",
    "max_time_diff": "sequence.max_time_diff",
}


def setting(param: typer.CallbackParam, value: Optional[float]) -> Optional[float]:
    """An option that sets a configuration key: checked by the key's own rule as the command line
    is parsed (:func:`annotate_rgbd.config.settings.setting_problem`), so that a value out of range
    is a usage error naming the option, as for every other option."""
    if value is not None:
        from annotate_rgbd.config.settings import setting_problem

        problem = setting_problem(OPTION_SETTINGS[param.name], value)
        if problem:
            raise typer.BadParameter(problem if ", got " in problem else f"{problem}, not {value:g}")
    return value
