"""Synthetic scenes with exact truth: the printed sheet, rendering, and the orbit, pivot and tilt-sweep scenarios."""
