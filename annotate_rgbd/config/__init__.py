"""Configuration: every setting with its default and source, read from TOML, presets and ``--set``.

:func:`load_config` is the documented entry (``annotate_rgbd.config.load_config``); the settings
themselves live in :mod:`annotate_rgbd.config.settings` (``cvat2mask``'s sections and the loader),
:mod:`annotate_rgbd.config.propose` (``[detect]``, ``[propose]``, ``[link]``) and
:mod:`annotate_rgbd.config.evaluate` (``[evaluate]``); the bounded TOML reader is
:mod:`annotate_rgbd.config.toml_input`, the ``--set`` and ``--part`` texts
:mod:`annotate_rgbd.config.command_line`.
"""

from annotate_rgbd.config.command_line import parse_part_offsets, parse_settings  # noqa: F401
from annotate_rgbd.config.settings import (  # noqa: F401  (the documented import path)
    Config,
    config_from_dict,
    config_to_dict,
    load_config,
    preset_names,
)
