"""Scoring plane masks against ground truth with the EVOPS metrics."""
