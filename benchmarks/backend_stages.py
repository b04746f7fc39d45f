"""Benchmark the backend per keyframe: CPU milliseconds of each local-mapping step on a recording's keyframes.

A lockstep run's recorded ``frontend/keyframe`` messages are fed, in order, to a fresh
``BackendNode`` in this process, started with the stage processes' environment (pinned math
kernels, single-threaded BLAS: ``zenslam.runtime.supervisor.stage_environment``). The local
mapper's own step timers (insertion, point culling, triangulation, fusion, local BA, keyframe
culling) are read in CPU time rather than wall time, so that other work on a shared machine
counts less; ``ba_optimize`` is the bundle adjuster alone, ``refresh`` the point refreshes inside
the steps, ``non_ba`` the whole keyframe less ``ba_optimize``. Also printed: a digest of the map
updates, equal between two versions of the code exactly when their lockstep output is.

Run: ``.venv/bin/python benchmarks/backend_stages.py RUN/run.mcap [--repeat 2]``
(make a run with ``zenslam run kitti:/work/shared/data/kitti_odometry/sequences/06 --run-id k0``;
writes benchmarks/results/backend_stages.json).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
import types
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "backend_stages.json"
_MARK = "ZENSLAM_BACKEND_STAGES_CHILD"
STEPS = (
    "insertion", "point_culling", "triangulation", "fusion", "local_ba", "ba_optimize", "keyframe_culling",
    "loop_closing", "refresh", "total", "step", "non_ba",
)  # fmt: skip


def _cpu_timed(owner, name: str, sums: dict[str, float], key: str) -> None:
    """Wrap ``owner.name`` to add its CPU milliseconds to ``sums[key]``."""
    inner = getattr(owner, name)

    def timed(*args, **kwargs):
        start = time.process_time()
        try:
            return inner(*args, **kwargs)
        finally:
            sums[key] = sums.get(key, 0.0) + (time.process_time() - start) * 1e3

    setattr(owner, name, timed)


def measure(recording: Path, repeat: int) -> tuple[list[dict[str, float]], list[str]]:
    """Per-keyframe CPU ms of each step (one dict per keyframe and repetition) and each repetition's digest."""
    import numpy as np  # noqa: F401  (loaded after the environment is pinned)

    from zenslam.backend import local_mapping, node
    from zenslam.backend.config import BackendConfig
    from zenslam.backend.map import BackendMap
    from zenslam.backend.node import BackendNode
    from zenslam.schemas import codec
    from zenslam.service.replay import KEYFRAME_TOPIC, read_topics

    cpu_clock = types.SimpleNamespace(perf_counter=time.process_time)
    local_mapping.time = cpu_clock  # the stages' own timers, on CPU time
    node.time = cpu_clock
    extra: dict[str, float] = {}
    _cpu_timed(BackendMap, "refresh_points", extra, "refresh")
    messages = [codec.decode_keyframe(m.data) for m in read_topics(recording, (KEYFRAME_TOPIC,))[KEYFRAME_TOPIC]]
    keyframes = [m for m in messages if not isinstance(m, codec.EndOfStream)]
    rows, digests = [], []
    for _ in range(repeat):
        backend = BackendNode.from_config(BackendConfig())
        _cpu_timed(backend.mapper.bundle_adjuster, "optimize", extra, "ba_optimize")
        digest = hashlib.sha256()
        for keyframe in keyframes:
            extra.clear()
            start = time.process_time()
            out = backend.step(keyframe)
            step = (time.process_time() - start) * 1e3
            for update in out.updates:
                digest.update(codec.encode_map_update(update))
            row = {**backend.mapper.last_timings_ms, **extra, "step": step}
            row["non_ba"] = step - extra.get("ba_optimize", 0.0)
            rows.append(row)
        digests.append(digest.hexdigest()[:16])
    return rows, digests


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path, help="a lockstep run's run.mcap")
    parser.add_argument("--repeat", type=int, default=1, help="fresh backends fed the keyframes one after the other")
    args = parser.parse_args()
    if os.environ.get(_MARK) != "1":
        from zenslam.runtime.supervisor import stage_environment

        env = {**stage_environment(os.environ), _MARK: "1"}
        os.execve(sys.executable, [sys.executable, *sys.argv], env)
    import numpy as np

    rows, digests = measure(args.recording, args.repeat)
    print(f"{args.recording}: {len(rows) // args.repeat} keyframes x {args.repeat}; map updates digest {', '.join(digests)}")
    print(f"{'CPU ms per keyframe':22s} {'median':>8s} {'mean':>8s} {'max':>8s}")
    summary = {}
    for step in STEPS:
        values = np.array([row.get(step, 0.0) for row in rows])
        summary[step] = {"median_ms": float(np.median(values)), "mean_ms": float(values.mean()), "max_ms": float(values.max())}
        print(f"{step:22s} {np.median(values):8.2f} {values.mean():8.2f} {values.max():8.2f}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"recording": str(args.recording), "digests": digests, "steps": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
