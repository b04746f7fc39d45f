"""What the source and recorder processes import: neither the SLAM stages' libraries (gtsam, the rerun
SDK) nor the bag-of-words vocabulary, so that each holds only the memory of what it does.

Each stage's module is imported in a fresh interpreter, which then does that stage's work off the
bus (the source renders and encodes frames, the recorder records them, images included, to an MCAP
file); its ``sys.modules`` then shows what the process loaded.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

# Packages neither process uses: the backend's solver, the viewer's SDK (and the pyarrow it loads),
# the vocabulary's code (its data is ~18 MB once loaded).
NOT_IMPORTED = ("gtsam", "rerun", "pyarrow", "zenslam.vocabulary")

_SOURCE_WORK = """
from zenslam.service import source_node
from zenslam.schemas import codec
from zenslam.service.sources import open_source

source = open_source("synthetic:loop/stereo", None)
for _, frame in zip(range(2), source):
    codec.encode_sensor_frame(frame, source.calibration, source.sensor, "synthetic")
"""

_RECORDER_WORK = """
import numpy as np
from zenslam.camera import PinholeCalibration
from zenslam.schemas import codec, keys
from zenslam.service import mcap_io, recorder
from zenslam.service.recorder_config import RecorderConfig
from zenslam.service.sources.frame import SensorFrame

calibration = PinholeCalibration(fx=100.0, fy=100.0, cx=16.0, cy=12.0, width=32, height=24, baseline_m=0.1)
image = np.arange(32 * 24, dtype=np.uint8).reshape(24, 32)
writer = mcap_io.RecordingWriter(OUTPUT)
rec = recorder.Recorder(writer, RecorderConfig(), "s")
for i in range(2):
    message = codec.encode_sensor_frame(SensorFrame(i, 1_000 + i, image, image), calibration, "stereo")
    rec.record(keys.sensor_frame("s"), f"application/protobuf;{codec.SENSOR_FRAME}", message)
rec.finish()
"""

_REPORT = """
import json, sys
print(json.dumps(sorted(sys.modules)))
"""


def modules_after(work: str, tmp_path: Path) -> set[str]:
    """The modules a fresh interpreter holds after ``work`` (``OUTPUT``: a file path in ``tmp_path``)."""
    code = f"OUTPUT = {str(tmp_path / 'out.mcap')!r}\n{work}\n{_REPORT}"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    return set(json.loads(result.stdout.strip().splitlines()[-1]))


def loaded(modules: set[str], package: str) -> list[str]:
    return sorted(m for m in modules if m == package or m.startswith(package + "."))


@pytest.mark.parametrize("stage, work", [("source", _SOURCE_WORK), ("recorder", _RECORDER_WORK)])
def test_the_stage_imports_no_gtsam_rerun_nor_vocabulary(stage: str, work: str, tmp_path: Path):
    modules = modules_after(work, tmp_path)
    module = {"source": "zenslam.service.source_node", "recorder": "zenslam.service.recorder"}[stage]
    assert module in modules  # the stage's own module was imported, with everything it imports
    for package in NOT_IMPORTED:
        assert not loaded(modules, package), f"the {stage} imports {loaded(modules, package)[:5]}"
    if stage == "recorder":
        assert (tmp_path / "out.mcap").stat().st_size > 0
