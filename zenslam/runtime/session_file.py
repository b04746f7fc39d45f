"""How a program outside a run finds it: ``session.json`` in the run folder names its bus session and endpoints.

``zenslam run`` writes it when its hub session is open, before any stage starts:
``{"session": "<run-id>", "connect": ["tcp/127.0.0.1:40211"]}``. ``connect`` holds the hub's
listening endpoint (empty when the run's zenoh config comes from ``--bus-config``: that file says
where its routers are). ``zenslam.client`` reads it to join the run.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from zenslam.errors import ConfigError

SESSION_FILENAME = "session.json"


@dataclass(frozen=True)
class SessionInfo:
    """A run's bus session name (its run id) and the zenoh endpoints to connect to, to join it."""

    session: str
    connect: tuple[str, ...] = ()


def write_session_file(run_dir: Path, info: SessionInfo) -> Path:
    """Write ``run_dir/session.json`` (atomically: a reader never sees half of it)."""
    path = Path(run_dir) / SESSION_FILENAME
    partial = path.with_suffix(".json.partial")
    partial.write_text(json.dumps({"session": info.session, "connect": list(info.connect)}, indent=2) + "\n")
    partial.replace(path)
    return path


def read_session_file(run_dir: Path, timeout_s: float = 0.0) -> SessionInfo:
    """The session of the run folder ``run_dir``, waiting up to ``timeout_s`` seconds for its
    ``session.json`` to appear (a run started a moment ago writes it once its bus is up)."""
    path = Path(run_dir) / SESSION_FILENAME
    deadline = time.monotonic() + timeout_s
    while not path.is_file():
        if time.monotonic() >= deadline:
            raise ConfigError(
                f"{path} does not exist (waited {timeout_s:.0f} s): is a `zenslam run` writing to {Path(run_dir)}? "
                "Runs started before session.json existed cannot be joined this way; give the session and endpoint"
            )
        time.sleep(0.05)
    try:
        data = json.loads(path.read_text())
        return SessionInfo(str(data["session"]), tuple(str(e) for e in data.get("connect", ())))
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path} is not a zenslam session file ({exc}); expected {{\"session\": ..., \"connect\": [...]}}") from exc
