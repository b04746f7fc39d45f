"""zenslam: a visual SLAM service (ORB-SLAM algorithms, GTSAM back end, zenoh processes)."""

__version__ = "0.1.0"
