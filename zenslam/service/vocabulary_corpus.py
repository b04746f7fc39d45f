"""The training corpus of a vocabulary: ORB descriptors of sources' frames, extracted as tracking extracts them.

Each image of a frame (left, and right for stereo) is one training document. Descriptors come from
the frontend's ORB extractor with the frontend's default ORB settings, so the words are those of the
features that tracking looks up. Synthetic scenes can be rendered with several texture seeds.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from zenslam.errors import FrameReadError, SourceSpecError
from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.orb_extractor import OrbExtractor
from zenslam.service.sources import Source, open_source

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CorpusPart:
    """What one source gave: its name, frames used (and skipped as unreadable), images, descriptors."""

    name: str
    frames: int
    skipped: int
    images: int
    descriptors: int

    def describe(self) -> str:
        skipped = f", {self.skipped} unreadable frames skipped" if self.skipped else ""
        return f"{self.name}: {self.frames} frames, {self.images} images, {self.descriptors} descriptors{skipped}"


def parse_seeds(text: str) -> tuple[int, ...]:
    """Seeds from "0-7", "1,4,9" or a mix ("0-3,10")."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            first, dash, last = part.strip().partition("-")
            seeds.extend(range(int(first), int(last) + 1) if dash else [int(first)])
    except ValueError:
        raise SourceSpecError(f"synthetic seeds {text!r}: use numbers and ranges such as 0-7 or 1,4,9") from None
    if not seeds:
        raise SourceSpecError(f"synthetic seeds {text!r} name no seed")
    return tuple(seeds)


def open_training_sources(specs: Sequence[str], synthetic_seeds: Sequence[int] | None = None) -> list[Source]:
    """The sources named by ``specs`` (as ``zenslam run`` takes them); each synthetic scene once per seed."""
    sources: list[Source] = []
    for spec in specs:
        if spec.split(":")[0] == "synthetic" and synthetic_seeds:
            from zenslam.service.sources.synthetic import SCENE_NAMES, SyntheticSource, scene_config

            scene, _, sensor = (spec.partition(":")[2] or "loop").partition("/")
            if scene not in SCENE_NAMES:
                raise SourceSpecError(f"unknown synthetic scene {scene!r}: choose one of {sorted(SCENE_NAMES)}")
            overrides = {"sensor": sensor} if sensor else {}
            sources.extend(SyntheticSource(scene_config(scene, seed=seed, **overrides)) for seed in synthetic_seeds)
        else:
            sources.append(open_source(spec))
    return sources


def frame_indices(count: int, max_frames: int | None) -> np.ndarray:
    """All ``count`` frame indices, or ``max_frames`` of them spread evenly over the sequence."""
    if max_frames is None or count <= max_frames:
        return np.arange(count)
    return np.unique(np.round(np.linspace(0, count - 1, max_frames)).astype(np.int64))


def source_label(source: Source) -> str:
    seed = getattr(getattr(source, "config", None), "seed", None)
    return f"{source.name} (seed {seed})" if seed is not None else source.name


def collect_descriptors(
    sources: Sequence[Source],
    max_frames_per_source: int | None = None,
    on_frame: Callable[[], None] | None = None,
) -> tuple[list[np.ndarray], list[CorpusPart]]:
    """(one (N, 32) uint8 descriptor array per image, a summary per source). Frames that cannot be
    read are skipped with a warning, as a run skips them."""
    extractor = OrbExtractor(FrontendConfig().orb)
    images: list[np.ndarray] = []
    parts: list[CorpusPart] = []
    for source in sources:
        label = source_label(source)
        first_image = len(images)
        used = skipped = 0
        for index in frame_indices(len(source), max_frames_per_source).tolist():
            try:
                frame = source.frame(index)
            except FrameReadError as exc:
                logger.warning("%s: skipping frame %d: %s", label, index, exc)
                skipped += 1
                continue
            if frame.right is not None:
                (left, _), (right, _) = extractor.extract_pair(frame.left, frame.right)
                images.extend([left.descriptors, right.descriptors])
            else:
                images.append(extractor.extract(frame.left)[0].descriptors)
            used += 1
            if on_frame is not None:
                on_frame()
        count = sum(d.shape[0] for d in images[first_image:])
        parts.append(CorpusPart(label, used, skipped, len(images) - first_image, count))
    return images, parts
