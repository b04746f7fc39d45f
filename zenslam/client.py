"""The Python client of a zenslam run under its public name: ``from zenslam.client import Client``.

The client lives with the rest of the service (``zenslam.service.client``), above the stages and
the runtime it uses; this module keeps the name that programs import.
"""

from zenslam.service.client import (
    Client,
    ClientError,
    KeyframeTrajectory,
    MapSnapshot,
    MapUpdate,
    PinholeCalibration,
    Pose,
    RunEnd,
    SensorFrame,
    TrackingState,
)

__all__ = [
    "Client", "ClientError", "KeyframeTrajectory", "MapSnapshot", "MapUpdate", "PinholeCalibration", "Pose",
    "RunEnd", "SensorFrame", "TrackingState",
]  # fmt: skip
