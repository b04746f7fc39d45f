"""The backend's configuration: the ``backend`` section of a run's YAML (keys equal the field names)."""

from __future__ import annotations

from dataclasses import dataclass, field

from zenslam.backend.ba_problem import LocalBAConfig
from zenslam.backend.local_mapping import LocalMappingConfig
from zenslam.backend.loop_closing_config import LoopClosingConfig
from zenslam.errors import ConfigError

# Where the backend's config holds its copy of the run's ``map`` section (``MapRulesConfig``),
# which local mapping builds the map's covisibility graph with; the service fills it from ``map``.
MAP_RULES_PATH = ("local_mapping", "map_rules")

@dataclass(frozen=True)
class BackendConfig:
    """The backend process (the ``backend`` section): local mapping, local BA and its queues."""

    local_mapping: LocalMappingConfig = field(default_factory=LocalMappingConfig)
    local_ba: LocalBAConfig = field(default_factory=LocalBAConfig)
    loop_closing: LoopClosingConfig = field(default_factory=LoopClosingConfig)
    # Bag-of-words vocabulary for place recognition: a file (ours, or DBoW2 text as ORB-SLAM's
    # ORBvoc.txt); empty = the vocabulary shipped with zenslam.
    vocabulary: str = ""  # path
    # A saved map (``zenslam run --map``; format in backend/map_file.py) the backend starts from:
    # its keyframes answer relocalisation queries and new keyframes extend it. Empty = a new map.
    map_file: str = ""  # path
    # Where the map is written when the keyframe stream ends (after a running global BA has
    # finished); empty = not written.
    save_map: str = ""  # path
    # Before the map is saved at the end of a run, one global BA over all of it (when loop closing's
    # global BA is enabled); its correction is published, so the run's final trajectory has it too.
    global_ba_before_save: bool = True
    # Keyframes the backend's inbox holds; when full the frontend's send blocks (lossless: never dropped).
    keyframe_queue: int = 32  # keyframes
    # After its input's end of stream the backend keeps answering backend/map and backend/trajectory
    # for this long (or until stopped: ``zenslam run`` stops it once it has the final trajectory).
    linger_s: float = 60.0  # seconds
    # Added to the backend process's nice value (0-19, POSIX niceness) in live runs: mapping yields
    # the CPU to tracking, which must keep up with its camera, as ORB-SLAM's tracking is its
    # real-time thread. Scheduling only: the numerics are the same at any value. A small increment
    # keeps live frames from being dropped without starving mapping, which a large one does. Where
    # frames wait for tracking (lockstep, pipelined) mapping keeps its priority: a backend that
    # yields there falls behind, the keyframe throttle holds keyframes back and the map loses scale
    # (benchmarks/stage_priorities.md).
    nice: int = 5  # niceness increment
    # Append every keyframe mapped to backend.journal in the run folder, so that a backend restarted
    # after a crash rebuilds the same map (backend/journal.py); false: a restarted backend starts empty.
    journal: bool = True
    # Publish each keyframe's answer (its insertion, new points and fusion) before its local BA, and
    # the BA's changes after it as a correction: a lockstep frontend tracks the next frame on the
    # answer while the BA runs (local mapping counts as busy, as ORB-SLAM's tracking thread sees its
    # local-mapping thread), and applies the correction before the frame after (a lag of one frame,
    # the same in every run). Stereo and RGB-D keyframes only: a monocular one is answered after its
    # BA (``BackendNode.answers_before_local_ba``). false: every answer waits for its local BA, and
    # tracking with it. Measured in benchmarks/local_mapping.md.
    answer_before_local_ba: bool = True

    def __post_init__(self) -> None:
        if not 0 <= self.nice <= 19:
            raise ConfigError(f"backend.nice={self.nice} must be within 0..19 (a niceness increment; 0 leaves it as is)")
        if self.keyframe_queue < 1:
            raise ConfigError(f"backend.keyframe_queue={self.keyframe_queue} must be at least 1 message")
        if not self.linger_s >= 0:
            raise ConfigError(f"backend.linger_s={self.linger_s} must be >= 0 seconds")
