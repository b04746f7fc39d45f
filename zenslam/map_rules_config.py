"""The ``map`` section of a run: the map rules both stages apply, set once for the run."""

from __future__ import annotations

from dataclasses import dataclass

from zenslam.errors import ConfigError


@dataclass(frozen=True)
class MapRulesConfig:
    """Settings of the rules the frontend's map cache and the backend's map share
    (``zenslam.covisibility_rules``); each stage's config carries a copy, filled by the service
    from the run's ``map`` section so the two cannot drift apart."""

    # Shared map points for a covisibility edge (ORB-SLAM: 15; 15..30 allowed): the ordered
    # connections of the frontend's local-map search and of the backend's local mapping.
    min_covisibility_weight: int = 15  # map points

    def __post_init__(self) -> None:
        if not 15 <= self.min_covisibility_weight <= 30:
            raise ConfigError(
                f"map.min_covisibility_weight={self.min_covisibility_weight} must be within 15..30 "
                "(ORB-SLAM's covisibility threshold)"
            )
