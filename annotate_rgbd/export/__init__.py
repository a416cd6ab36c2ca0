"""Exports of a finished run for other tools (CVAT for corrections)."""
