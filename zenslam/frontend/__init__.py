"""Tracking: ORB extraction, frames, motion model, local-map tracking, pose optimisation, keyframe decision."""
