"""Scene presets for ``--config NAME``: a package only so that they install with annotate_rgbd."""
