"""benchmarks/footprint.py's samplers: PSS and RSS read from /proc, and each process's peaks through a run."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
_MB = 1e6


@pytest.fixture(scope="module")
def footprint():
    spec = importlib.util.spec_from_file_location("footprint", BENCHMARKS / "footprint.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["footprint"] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_pss_of_this_process_grows_with_its_private_pages_and_stays_within_its_rss(footprint):
    before = footprint.pss_bytes(os.getpid())
    block = np.ones(50_000_000 // 8)  # 50 MB written: private pages, counted in full in the PSS
    after = footprint.pss_bytes(os.getpid())
    rss = footprint.rss_bytes(os.getpid())
    assert block[-1] == 1.0
    assert after - before >= 45 * _MB
    assert 0 < after <= rss <= footprint.vm_hwm_bytes(os.getpid())


def test_a_process_that_is_gone_has_no_pss_rss_nor_peak(footprint):
    gone = 2**22 + 1  # above the kernel's largest pid (pid_max is at most 2**22)
    assert footprint.pss_bytes(gone) is None and footprint.rss_bytes(gone) is None and footprint.vm_hwm_bytes(gone) is None


def test_a_sampled_run_keeps_each_process_peak_pss_beside_its_peak_rss(footprint):
    # A parent holding 20 MB that starts a child holding 60 MB, both for long enough to be sampled.
    child = "import numpy, time; b = numpy.ones(60_000_000 // 8); time.sleep(1.0)"
    parent = f"import numpy, subprocess, sys; b = numpy.ones(20_000_000 // 8); subprocess.run([sys.executable, '-c', {child!r}])"
    sampled = footprint.run_sampled([sys.executable, "-c", parent], interval_s=0.05)
    assert sampled.result.returncode == 0
    assert len(sampled.peak_rss) == 2 and sampled.peak_pss.keys() == sampled.peak_rss.keys()
    small, large = sorted(sampled.peak_pss.values())
    assert small >= 20 * _MB and large >= 60 * _MB
    for name, pss in sampled.peak_pss.items():
        assert pss <= sampled.peak_rss[name]
    assert sampled.together["pss"] <= sum(sampled.peak_pss.values())
