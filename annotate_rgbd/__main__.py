"""``python -m annotate_rgbd``: the same as the ``annotate-rgbd`` command."""

from annotate_rgbd.cli import app

app(prog_name="annotate-rgbd")
