"""DBoW2's text vocabulary format, the one ORB-SLAM2/3 load (ORBvoc.txt), plain or gzip-compressed.

First line ``k L scoring weighting`` (codes of DBoW2's enums; ORB vocabularies are ``0 0``: L1-norm
scoring, TF-IDF weighting). Then one line per node after the root, in node-id order (node i on line
i + 1): ``parent_id is_leaf d0 ... d31 weight``, the descriptor as 32 decimal bytes (FORB::toString),
the weight the word's idf (0 for inner nodes). ORB-SLAM reads it with ``loadFromTextFile``; nodes
are written as DBoW2's ``saveToTextFile`` writes them.
"""

from __future__ import annotations

import gzip
import io
import warnings
from pathlib import Path

import numpy as np

from zenslam.errors import VocabularyError
from zenslam.vocabulary.vocabulary import DESCRIPTOR_BYTES, Vocabulary

SCORING_NAMES = ("L1-norm", "L2-norm", "chi-square", "KL-divergence", "Bhattacharyya", "dot product")
WEIGHTING_NAMES = ("tf-idf", "tf", "idf", "binary")
L1_NORM, TF_IDF = 0, 0  # the only codes zenslam scores with
_FIELDS = 2 + DESCRIPTOR_BYTES + 1  # parent, leaf flag, descriptor bytes, weight
_BYTE_TEXT = [f"{value} " for value in range(256)]


def parse_dbow2_text(data: bytes, source: str) -> Vocabulary:
    """The vocabulary in DBoW2 text ``data`` (already decompressed); VocabularyError naming ``source``."""
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as exc:
        raise VocabularyError(
            f"vocabulary {source}: not a text file (byte {exc.start} is not ASCII): give a zenslam .npz vocabulary "
            "or a DBoW2 text vocabulary such as ORB-SLAM's ORBvoc.txt"
        ) from None
    header, _, body = text.partition("\n")
    branching, depth = _parse_header(header, source)
    values = _parse_numbers(body, source)
    table = values.reshape(-1, _FIELDS)
    _check_rows(table, source)
    n = table.shape[0] + 1
    parents = np.concatenate(([-1], table[:, 0].astype(np.int64)))
    bad = np.flatnonzero(parents[1:] >= np.arange(1, n))
    if bad.size:
        node = int(bad[0]) + 1
        raise VocabularyError(
            f"vocabulary {source}, line {node + 1}: node {node} names parent {int(parents[node])}, which is not an "
            "earlier node: the file is corrupt"
        )
    descriptors = np.zeros((n, DESCRIPTOR_BYTES), dtype=np.uint8)  # the root's is not in the file
    descriptors[1:] = table[:, 2 : 2 + DESCRIPTOR_BYTES]
    vocabulary = Vocabulary(branching, depth, parents, descriptors, np.concatenate(([0.0], table[:, -1])), source=source)
    marked_leaf = np.concatenate(([False], table[:, 1] == 1))
    wrong = np.flatnonzero(marked_leaf != vocabulary.is_leaf)
    if wrong.size:
        node = int(wrong[0])
        said, has = ("a leaf", "has children") if marked_leaf[node] else ("an inner node", "has no children")
        raise VocabularyError(
            f"vocabulary {source}, line {node + 1}: node {node} is marked as {said} but {has}: the file is truncated "
            "or corrupt; get a complete copy"
        )
    return vocabulary


def _parse_header(header: str, source: str) -> tuple[int, int]:
    fields = header.split()
    try:
        k, depth, scoring, weighting = (int(f) for f in fields)
    except ValueError:
        raise VocabularyError(
            f"vocabulary {source}: the first line {header[:80]!r} is not DBoW2's 'k L scoring weighting' (four "
            "integers): not a DBoW2 text vocabulary"
        ) from None
    if not (2 <= k <= 20 and 1 <= depth <= 10):
        raise VocabularyError(f"vocabulary {source}: k={k}, L={depth} out of DBoW2's range (k 2-20, L 1-10): the header is corrupt")
    if scoring != L1_NORM:
        name = SCORING_NAMES[scoring] if 0 <= scoring < len(SCORING_NAMES) else "unknown"
        raise VocabularyError(
            f"vocabulary {source}: scoring code {scoring} ({name}) is not supported: zenslam scores with L1-norm "
            "(code 0), as ORB-SLAM's ORBvoc.txt does; use an L1/TF-IDF vocabulary (header 'k L 0 0')"
        )
    if weighting != TF_IDF:
        name = WEIGHTING_NAMES[weighting] if 0 <= weighting < len(WEIGHTING_NAMES) else "unknown"
        raise VocabularyError(
            f"vocabulary {source}: weighting code {weighting} ({name}) is not supported: zenslam weights words by "
            "TF-IDF (code 0), as ORB-SLAM's ORBvoc.txt does; use an L1/TF-IDF vocabulary (header 'k L 0 0')"
        )
    return k, depth


def _parse_numbers(body: str, source: str) -> np.ndarray:
    """All numbers of the node lines, (lines * 35,) float64; on any malformed line, an error naming it."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            values = np.fromstring(body, dtype=np.float64, sep=" ")  # any whitespace separates
        except (DeprecationWarning, ValueError):
            values = None
    lines = sum(1 for line in body.splitlines() if line.strip())
    if values is None or values.size != lines * _FIELDS:
        raise _first_bad_line(body, source)
    if lines == 0:
        raise VocabularyError(f"vocabulary {source}: no nodes after the header: the file is truncated")
    return values


def _first_bad_line(body: str, source: str) -> VocabularyError:
    for number, line in enumerate(body.splitlines(), start=2):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != _FIELDS:
            values = len(fields) - 3
            hint = (
                f"descriptors of {values} values: zenslam needs 256-bit ORB descriptors ({DESCRIPTOR_BYTES} bytes)"
                + (" (64 values: a SURF vocabulary?)" if values == 64 else "")
                if values > 0 and len(fields) > _FIELDS
                else "the file is truncated or corrupt"
            )
            return VocabularyError(
                f"vocabulary {source}, line {number}: {len(fields)} fields, expected {_FIELDS} (parent, leaf flag, "
                f"{DESCRIPTOR_BYTES} descriptor bytes, weight): {hint}"
            )
        for field in fields:
            try:
                float(field)
            except ValueError:
                return VocabularyError(f"vocabulary {source}, line {number}: {field[:20]!r} is not a number: the file is corrupt")
    return VocabularyError(f"vocabulary {source}: the node lines cannot be read: the file is corrupt")


def _check_rows(table: np.ndarray, source: str) -> None:
    def fail(row: int, problem: str) -> VocabularyError:
        return VocabularyError(f"vocabulary {source}, line {row + 2}: {problem}")

    parent, leaf = table[:, 0], table[:, 1]
    descriptor, weight = table[:, 2 : 2 + DESCRIPTOR_BYTES], table[:, -1]
    bad = np.flatnonzero((parent != np.round(parent)) | (parent < 0))
    if bad.size:
        raise fail(int(bad[0]), f"parent {parent[bad[0]]} is not a node id: the file is corrupt")
    bad = np.flatnonzero((leaf != 0) & (leaf != 1))
    if bad.size:
        raise fail(int(bad[0]), f"leaf flag {leaf[bad[0]]} is not 0 or 1: the file is corrupt")
    not_byte = (descriptor != np.round(descriptor)) | (descriptor < 0) | (descriptor > 255)
    bad = np.flatnonzero(not_byte.any(axis=1))
    if bad.size:
        value = descriptor[bad[0]][not_byte[bad[0]]][0]
        raise fail(
            int(bad[0]),
            f"descriptor value {value} is not a byte (0-255): zenslam needs 256-bit ORB descriptors "
            f"({DESCRIPTOR_BYTES} bytes per node), not float descriptors such as SURF's",
        )
    bad = np.flatnonzero(~np.isfinite(weight) | (weight < 0))
    if bad.size:
        raise fail(int(bad[0]), f"weight {weight[bad[0]]} is not a finite, non-negative idf: the file is corrupt")


def format_dbow2_text(vocabulary: Vocabulary) -> str:
    """The vocabulary as DBoW2 text (header "k L  0 0", then one line per node after the root)."""
    out = io.StringIO()
    out.write(f"{vocabulary.branching} {vocabulary.depth}  {L1_NORM} {TF_IDF}\n")
    leaf = vocabulary.is_leaf.astype(np.int64).tolist()
    parents = vocabulary.parents.tolist()
    weights = vocabulary.weights.tolist()
    byte_text = _BYTE_TEXT
    for node, row in enumerate(vocabulary.descriptors.tolist()):
        if node == 0:
            continue
        # weights as Python's shortest round-trip repr, so that reading the file back gives the same bits
        out.write(f"{parents[node]} {leaf[node]} {''.join(byte_text[b] for b in row)} {weights[node]!r}\n")
    return out.getvalue()


def write_dbow2_text(vocabulary: Vocabulary, path: Path) -> None:
    """Write DBoW2 text to ``path``, gzip-compressed when it ends in .gz (reproducible: no timestamp)."""
    data = format_dbow2_text(vocabulary).encode("ascii")
    if path.name.endswith(".gz"):
        with open(path, "wb") as raw, gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) as compressed:
            compressed.write(data)
    else:
        path.write_bytes(data)
