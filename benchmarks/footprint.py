"""Benchmark a run's footprint: the run folder's bytes (per file, run.mcap per channel) and each process's peak RSS.

Runs ``zenslam run [SOURCE] --lockstep`` (default: the built-in synthetic scene, all its frames)
into a temporary folder while sampling, every ``--interval`` seconds, ``VmHWM`` (the kernel's peak
resident set) of every process in the run's tree: the ``zenslam run`` hub and its source, frontend,
backend and recorder. A process's last sample is its peak up to that moment; the interval only
matters for growth in a process's last moments. Beside it, each process's PSS (proportional set
size, ``/proc/PID/smaps_rollup``: its private pages plus its share of the pages several processes
map) at every sample, and its largest: a sampled peak, so a lower bound (the kernel keeps no peak
of PSS). The sums of the per-process peaks are the most cautious figures (processes peak at
different times, so the real simultaneous peak is lower); the sum of peak PSS counts the shared
libraries once. It also sums, at every sample, the processes' current RSS, and their PSS (proportional set size:
pages several processes map, such as the rerun, gtsam and OpenCV libraries every stage loads, are
shared out among them instead of counted in full in each), and reports the largest of each sum;
the PSS sum is the memory the run holds at its fullest moment. Then it sums the run folder per
file and run.mcap per topic: the messages' own bytes (uncompressed) and their share of the file's compressed chunks (each chunk's compressed size
split across topics in proportion to what each topic's bytes in it compress to alone, with the
chunk's codec: PNG images that do not shrink are not credited with the map updates' compression).

RSS is barely affected by the machine's load; the wall time is (it is printed with the load average).

Run: ``.venv/bin/python benchmarks/footprint.py [SOURCE] [--max-frames N] [--config YAML] [--keep DIR]``
(writes benchmarks/results/footprint.json, or ``--results PATH``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import lz4.frame
import psutil
import zstandard
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "footprint.json"
_MB = 1e6


def vm_hwm_bytes(pid: int) -> int | None:
    """The peak resident set of process ``pid`` (bytes), or None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None
    return None


def process_name(proc: psutil.Process) -> str:
    """The stage a process of the run is: ``run`` (the hub) or the ``--stage``/module it was started with."""
    try:
        cmdline = proc.cmdline()
    except psutil.Error:
        return f"pid{proc.pid}"
    for module, name in (("zenslam.service.recorder", "recorder"), ("zenslam.service.source_node", "source"),
                         ("zenslam.frontend.node", "frontend"), ("zenslam.backend.node", "backend")):  # fmt: skip
        if module in cmdline:
            return name
    if "run" in cmdline:
        return "run"
    return f"{Path(cmdline[0]).name if cmdline else 'pid'}:{proc.pid}"


def pss_bytes(pid: int) -> int | None:
    """The proportional set size of process ``pid`` (bytes: its private pages plus its share of pages
    mapped by several processes, such as the libraries every stage loads), or None once it is gone."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as rollup:
            for line in rollup:
                if line.startswith("Pss:"):
                    return int(line.split()[1]) * 1024
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None
    return None


def rss_bytes(pid: int) -> int | None:
    """The resident set of process ``pid`` now (bytes), or None once it is gone."""
    try:
        with open(f"/proc/{pid}/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None


@dataclass(frozen=True)
class SampledRun:
    """What ``run_sampled`` saw of a command and its descendants, in bytes per stage (``process_name``)."""

    peak_rss: dict[str, int]  # each process's VmHWM (the kernel's peak resident set), summed per stage
    peak_pss: dict[str, int]  # each process's largest sampled PSS, summed per stage (a lower bound: PSS has no HWM)
    together: dict[str, int]  # "rss", "pss": the largest sums over the processes in any one sample
    wall_s: float
    result: subprocess.CompletedProcess


def run_sampled(command: list[str], interval_s: float) -> SampledRun:
    """Run ``command``, sampling every ``interval_s`` seconds the peak RSS (VmHWM) and the PSS of it and
    all its descendants."""
    peaks: dict[int, int] = {}
    pss_peaks: dict[int, int] = {}
    names: dict[int, str] = {}
    together = {"rss": 0, "pss": 0}
    start = time.perf_counter()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        popen = subprocess.Popen(command, stdout=out, stderr=err)
        root = psutil.Process(popen.pid)
        while popen.poll() is None:
            try:
                tree = [root, *root.children(recursive=True)]
            except psutil.Error:
                tree = []
            pss_now = {proc.pid: pss_bytes(proc.pid) for proc in tree}
            together["rss"] = max(together["rss"], sum(rss_bytes(proc.pid) or 0 for proc in tree))
            together["pss"] = max(together["pss"], sum(pss or 0 for pss in pss_now.values()))
            for proc in tree:
                hwm = vm_hwm_bytes(proc.pid)
                if hwm is None:
                    continue
                peaks[proc.pid] = max(peaks.get(proc.pid, 0), hwm)
                pss_peaks[proc.pid] = max(pss_peaks.get(proc.pid, 0), pss_now[proc.pid] or 0)
                # Named at every sample: a stage sampled between the supervisor's fork and its exec
                # still shows the hub's command line.
                names[proc.pid] = process_name(proc)
            time.sleep(interval_s)
        wall_s = time.perf_counter() - start
        out.seek(0)
        err.seek(0)
        result = subprocess.CompletedProcess(command, popen.returncode, out.read().decode(), err.read().decode())
    return SampledRun(_per_stage(peaks, names), _per_stage(pss_peaks, names), together, wall_s, result)


def _per_stage(per_pid: dict[int, int], names: dict[int, str]) -> dict[str, int]:
    """Bytes per pid summed per stage name (a restarted stage's processes together)."""
    per_stage: dict[str, int] = {}
    for pid, value in per_pid.items():
        per_stage[names[pid]] = per_stage.get(names[pid], 0) + value
    return per_stage


def folder_sizes(run_dir: Path) -> dict[str, int]:
    """Bytes of every file under ``run_dir``, by path relative to it, largest first."""
    sizes = {str(p.relative_to(run_dir)): p.stat().st_size for p in run_dir.rglob("*") if p.is_file()}
    return dict(sorted(sizes.items(), key=lambda kv: -kv[1]))


def compressed_size(data: bytes, compression: str) -> int:
    """Bytes of ``data`` compressed as an MCAP chunk with ``compression`` ("zstd", "lz4" or "") would be."""
    if compression == "zstd":
        return len(zstandard.compress(data))
    if compression == "lz4":
        return len(lz4.frame.compress(data))
    return len(data)


def mcap_channels(path: Path) -> dict[str, dict[str, float]]:
    """Per topic of an MCAP file: messages, their bytes, and their estimated share of the compressed chunks."""
    topics: dict[int, str] = {}
    stats: dict[str, dict[str, float]] = defaultdict(lambda: {"messages": 0, "bytes": 0, "stored_bytes": 0.0})
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Chunk):
                in_chunk: dict[str, list[bytes]] = defaultdict(list)
                for inner in breakup_chunk(record):
                    if isinstance(inner, Channel):
                        topics[inner.id] = inner.topic
                    elif isinstance(inner, Message):
                        in_chunk[topics[inner.channel_id]].append(inner.data)
                        stats[topics[inner.channel_id]]["messages"] += 1
                alone = {topic: compressed_size(b"".join(parts), record.compression) for topic, parts in in_chunk.items()}
                total = sum(alone.values()) or 1
                for topic, parts in in_chunk.items():
                    stats[topic]["bytes"] += sum(len(p) for p in parts)
                    stats[topic]["stored_bytes"] += len(record.data) * alone[topic] / total
            elif isinstance(record, Message):  # outside chunks: stored as is
                topic = topics[record.channel_id]
                stats[topic]["messages"] += 1
                stats[topic]["bytes"] += len(record.data)
                stats[topic]["stored_bytes"] += len(record.data)
    return dict(sorted(stats.items(), key=lambda kv: -kv[1]["stored_bytes"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", nargs="?", default=None, help="zenslam run's SOURCE (default: its default, the synthetic scene)")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--config", type=Path, default=None, help="a run config YAML passed to zenslam run")
    parser.add_argument("--interval", type=float, default=0.1, help="seconds between RSS samples")
    parser.add_argument("--keep", type=Path, default=None, help="write the run folder here instead of a temporary folder")
    parser.add_argument("--results", type=Path, default=RESULTS)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        output = args.keep or Path(tmp)
        run_id = f"footprint-{os.getpid()}"
        command = [sys.executable, "-m", "zenslam.service.cli", "run", *([args.source] if args.source else []), "--lockstep",
                   "--output", str(output), "--run-id", run_id, "--no-progress"]  # fmt: skip
        if args.max_frames is not None:
            command += ["--max-frames", str(args.max_frames)]
        if args.config is not None:
            command += ["--config", str(args.config)]
        load = os.getloadavg()[0]
        sampled = run_sampled(command, args.interval)
        peaks, pss_peaks, together, wall_s, result = sampled.peak_rss, sampled.peak_pss, sampled.together, sampled.wall_s, sampled.result
        if result.returncode != 0:
            raise SystemExit(f"{' '.join(command)} failed:\n{result.stdout[-2000:]}\n{result.stderr[-3000:]}")
        run_dir = output / run_id
        files = folder_sizes(run_dir)
        channels = mcap_channels(run_dir / "run.mcap")
    report = {
        "machine": platform.platform(),
        "command": " ".join(command[1:]),
        "wall_s": round(wall_s, 1),
        "load_1min_before": load,
        "folder_mb": round(sum(files.values()) / _MB, 2),
        "files_mb": {name: round(size / _MB, 3) for name, size in files.items()},
        "mcap_channels": {
            topic: {"messages": int(s["messages"]), "mb": round(s["bytes"] / _MB, 3), "stored_mb": round(s["stored_bytes"] / _MB, 3)}
            for topic, s in channels.items()
        },
        "peak_rss_mb": {name: round(peak / _MB, 1) for name, peak in sorted(peaks.items())},
        "peak_rss_sum_mb": round(sum(peaks.values()) / _MB, 1),
        "peak_pss_mb": {name: round(peak / _MB, 1) for name, peak in sorted(pss_peaks.items())},
        "peak_pss_sum_mb": round(sum(pss_peaks.values()) / _MB, 1),
        "peak_rss_together_mb": round(together["rss"] / _MB, 1),
        "peak_pss_together_mb": round(together["pss"] / _MB, 1),
    }
    print(f"{report['command']}\nwall {wall_s:.1f} s (load {load:.1f} before)")
    print(f"run folder {report['folder_mb']:.1f} MB")
    for name, mb in report["files_mb"].items():
        if mb >= 0.01:
            print(f"  {name:<32} {mb:9.2f} MB")
    print("run.mcap per topic (messages, message MB, estimated stored MB)")
    for topic, s in report["mcap_channels"].items():
        print(f"  {topic:<32} {s['messages']:6d} {s['mb']:9.2f} {s['stored_mb']:9.2f}")
    print(f"  {'':<12} {'peak RSS':>10} {'peak PSS':>10} (RSS: VmHWM; PSS: the largest sample, shared pages shared out)")
    for name, mb in report["peak_rss_mb"].items():
        print(f"  {name:<12} {mb:7.1f} MB {report['peak_pss_mb'].get(name, 0):7.1f} MB")
    print(f"  {'sum':<12} {report['peak_rss_sum_mb']:7.1f} MB {report['peak_pss_sum_mb']:7.1f} MB (each process at its own peak)")
    print(f"peak of the processes' RSS summed at one moment: {report['peak_rss_together_mb']:.1f} MB")
    print(f"peak of the processes' PSS summed at one moment: {report['peak_pss_together_mb']:.1f} MB (shared pages counted once)")
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
