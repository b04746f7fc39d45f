"""The stages of a run and how each is started: one arrangement for ``zenslam run`` and ``zenslam stage``.

``zenslam run`` starts every stage on one machine, under its supervisor; ``zenslam stage ROLE``
starts one by hand, on any machine of the zenoh network. Both give a stage the same module and
the same arguments from here, so the stages wait for each other in the same way whatever
starts them: the recorder (when ``recorder.enabled``) before anything is published, the backend
before the frontend tracks (its answers pace a lockstep run), the frontend before the source sends
(its states pace the frames). Every wait is on liveliness tokens, so the stages may start in any
order, on any machine; each waits up to ``bus.start_timeout_s`` for the ones it needs.
"""

from __future__ import annotations

from typing import Literal, get_args

from zenslam.errors import ConfigError

StageName = Literal["source", "frontend", "backend", "recorder"]
STAGE_NAMES: tuple[str, ...] = get_args(StageName)

# The module each stage runs with ``python -m``.
STAGE_MODULES: dict[str, str] = {
    "source": "zenslam.service.source_node",
    "frontend": "zenslam.frontend.node",
    "backend": "zenslam.backend.node",
    "recorder": "zenslam.service.recorder",
}

# The stages a recorder follows: it finishes once they have all come and gone.
FOLLOWED_STAGES = ("source", "frontend", "backend")


def stage_args(stage: StageName, recorder: bool, wait_for: tuple[str, ...] = ()) -> tuple[str, ...]:
    """The arguments ``stage`` gets besides the common ones (session, config, bus), in any arrangement.

    ``recorder``: a recorder runs (``recorder.enabled``), and every other stage waits for it before
    publishing, so that nothing goes unrecorded. ``wait_for``: more processes (a client's liveliness
    name, see ``zenslam.client``) that every publishing stage waits for, so that they hear all of it.
    """
    if stage == "recorder":
        return tuple(arg for followed in FOLLOWED_STAGES for arg in ("--follow", followed))
    heard = tuple(arg for name in (("recorder",) if recorder else ()) + tuple(wait_for) for arg in ("--wait-for", name))
    if stage == "backend":
        return heard
    if stage == "frontend":
        return ("--map-updates", "--wait-for", "backend", *heard)
    if stage == "source":
        return ("--wait-for", "frontend", *heard)
    raise ConfigError(f"unknown stage {stage!r}; give one of {list(STAGE_NAMES)}")

