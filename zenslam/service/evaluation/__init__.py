"""Trajectory evaluation: ATE/RPE with evo, metrics.json and plots."""
