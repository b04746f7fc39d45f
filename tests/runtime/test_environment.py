"""metrics.json's ``run.environment``: the interpreter, machine and library versions of a run."""

from __future__ import annotations

import json
import platform
from importlib import metadata

import cv2
import numpy as np

from zenslam.runtime import environment


def test_the_installed_libraries_are_named_with_their_versions():
    libraries = environment.library_versions()
    assert libraries["numpy"] == np.__version__
    assert libraries["gtsam"] == metadata.version("gtsam")
    opencv = [v for k, v in libraries.items() if k.startswith("opencv")]
    assert opencv and all(v.startswith(cv2.__version__) for v in opencv)  # 5.0.0.93 is OpenCV 5.0.0
    assert libraries["zenslam"] == metadata.version("zenslam")


def test_absent_distributions_are_left_out():
    assert environment.library_versions(("numpy", "no-such-distribution-zenslam-test")) == {"numpy": np.__version__}


def test_the_description_is_json_ready_and_names_the_interpreter():
    described = json.loads(json.dumps(environment.describe()))
    assert described["python"] == platform.python_version() and described["machine"] == platform.machine()
    assert described["cpu_count"] >= 1 and "numpy" in described["libraries"]
