"""Reviewing a run: overlays, the offline review page, the contact sheet."""
