"""Benchmark the recorder's encoding costs on a recorded run: MCAP chunk compression and viewer image format.

Reads a run's ``run.mcap`` (e.g. a lockstep KITTI 06 clip run) and, ``--repeats`` times in turn:
- rewrites every message with zstd, lz4 and uncompressed chunks (the recorder's writer, same chunk
  size) and records the writer's CPU seconds and the file size;
- encodes every recorded left/right image (from /sensor/frame) as the viewer's
  foxglove.CompressedImage, PNG and JPEG (the recorder's own ``compressed_image``), and records CPU
  seconds and bytes.
CPU time (``time.process_time``) of this single-threaded process, so the figures hold on a loaded
machine better than wall times would.

Run: ``.venv/bin/python benchmarks/recorder_compression.py RUN.mcap [--repeats 3]``
(writes benchmarks/results/recorder_compression.json).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader

from zenslam.schemas import codec
from zenslam.service.mcap_io import RecordingWriter, iter_messages
from zenslam.service.recorder import compressed_image
from zenslam.service.run_config import RecorderConfig

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "recorder_compression.json"
COMPRESSIONS = ("zstd", "lz4", "none")


def read_messages(path: Path) -> list[tuple[str, str | None, int, bytes]]:
    """(topic, schema name, log time ns, data) of every message in the file, in log-time order."""
    with path.open("rb") as stream:
        return [
            (channel.topic, schema.name if schema else None, message.log_time, message.data)
            for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True)
        ]


def rewrite(messages, compression: str, out: Path) -> tuple[float, int]:
    """CPU seconds to write ``messages`` with ``compression`` chunks, and the file's bytes."""
    started = time.process_time()
    writer = RecordingWriter(out, compression=compression)
    for topic, schema, stamp_ns, data in messages:
        writer.write(topic, schema, data, stamp_ns)
    writer.finish()
    return time.process_time() - started, out.stat().st_size


def encode_images(images, image_format: str) -> tuple[float, int]:
    """CPU seconds to encode ``images`` as viewer CompressedImages in ``image_format``, and their bytes."""
    config = RecorderConfig(image_format=image_format)
    started = time.process_time()
    size = sum(len(compressed_image(image, stamp_ns, config)) for stamp_ns, image in images)
    return time.process_time() - started, size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path, help="a run's run.mcap")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    messages = read_messages(args.recording)
    images = []
    for recorded in iter_messages(args.recording, ["/sensor/frame"]):  # whole frames, images put back
        message = codec.decode_sensor_frame(recorded.data)
        if isinstance(message, codec.FrameMessage):
            images += [(message.frame.stamp_ns, im) for im in (message.frame.left, message.frame.right) if im is not None]
    chunks = {c: [] for c in COMPRESSIONS}
    encodings = {f: [] for f in ("png", "jpeg")}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for compression in COMPRESSIONS:
                chunks[compression].append(rewrite(messages, compression, Path(tmp) / f"{compression}.mcap"))
            for image_format in encodings:
                encodings[image_format].append(encode_images(images, image_format))
    report = {"machine": platform.platform(), "recording": str(args.recording), "messages": len(messages), "images": len(images)}
    for name, runs in {**{f"chunks {c}": r for c, r in chunks.items()}, **{f"images {f}": r for f, r in encodings.items()}}.items():
        cpu = [round(c, 3) for c, _ in runs]
        report[name] = {"cpu_s": cpu, "cpu_s_median": statistics.median(cpu), "bytes": runs[0][1]}
        print(f"{name:<12} cpu {statistics.median(cpu):6.3f} s (runs {cpu}), {runs[0][1] / 1e6:7.2f} MB")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
