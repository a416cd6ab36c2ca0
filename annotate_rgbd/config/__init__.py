"""Configuration: every setting with its default and source, read from TOML, presets and ``--set``.

:func:`load_config` is the documented entry (``annotate_rgbd.config.load_config``); the settings
themselves live in :mod:`annotate_rgbd.config.settings`, the bounded TOML reader in
:mod:`annotate_rgbd.config.toml_input`.
"""

from annotate_rgbd.config.settings import (  # noqa: F401  (the documented import path)
    Config,
    config_from_dict,
    config_to_dict,
    load_config,
    parse_part_offsets,
    parse_settings,
    preset_names,
)
