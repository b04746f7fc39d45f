"""Re-export of zenslam.descriptors while frontend modules move to the shared import (temporary)."""

from zenslam.descriptors import hamming_distance, hamming_distance_pairs

__all__ = ["hamming_distance", "hamming_distance_pairs"]
