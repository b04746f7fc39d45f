"""Why a run stopped before its end: the error, and each stage that died, failed or hung.

``zenslam run`` writes its outputs whatever happened; a failure adds ``run.failures`` to
metrics.json (``stages``: one entry per failed stage) and ends the command with ``line``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path


@dataclasses.dataclass(frozen=True)
class RunFailure:
    """Why a run stopped before its end: the error, the frames the hub had by then, and each failed stage."""

    error: str
    frame: int
    stages: list[dict[str, object]]  # {stage, exit_code or signal, frame, hung_s if hung}: metrics.json run.failures

    def line(self, run_dir: Path) -> str:
        """The one line a failed run ends with (the error itself is logged before it)."""
        stages = ", ".join(f"the {f['stage']}: {_how_it_ended(f)}" for f in self.stages)
        return (
            f"the run failed at frame {self.frame}{f' ({stages})' if stages else ''}: wrote what it had to {run_dir} "
            "(metrics.json run.completed: false)"
        )


def _how_it_ended(failure: dict[str, object]) -> str:
    if "hung_s" in failure:
        return f"no progress for {failure['hung_s']:.0f} s, killed"
    return f"signal {failure['signal']}" if "signal" in failure else f"exit status {failure.get('exit_code')}"
