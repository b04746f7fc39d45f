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
_WEIGHT_WINDOW = 40  # characters before a line end searched for the weight (ORBvoc's are ~8; repr's at most 24)


def parse_dbow2_text(data: bytes, source: str) -> Vocabulary:
    """The vocabulary in DBoW2 text ``data`` (already decompressed); VocabularyError naming ``source``."""
    bad_byte = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) >= 128)
    if bad_byte.size:
        raise VocabularyError(
            f"vocabulary {source}: not a text file (byte {int(bad_byte[0])} is not ASCII): give a zenslam .npz "
            "vocabulary or a DBoW2 text vocabulary such as ORB-SLAM's ORBvoc.txt"
        )
    header, _, body = data.partition(b"\n")
    branching, depth = _parse_header(header.decode("ascii"), source)
    integers, weights = _parse_node_lines(body, source)
    _check_rows(integers, weights, source)
    n = integers.shape[0] + 1
    parents = np.concatenate(([-1], integers[:, 0]))
    bad = np.flatnonzero(parents[1:] >= np.arange(1, n))
    if bad.size:
        node = int(bad[0]) + 1
        raise VocabularyError(
            f"vocabulary {source}, line {node + 1}: node {node} names parent {int(parents[node])}, which is not an "
            "earlier node: the file is corrupt"
        )
    descriptors = np.zeros((n, DESCRIPTOR_BYTES), dtype=np.uint8)  # the root's is not in the file
    descriptors[1:] = integers[:, 2:]
    vocabulary = Vocabulary(branching, depth, parents, descriptors, np.concatenate(([0.0], weights)), source=source)
    marked_leaf = np.concatenate(([False], integers[:, 1] == 1))
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


def _parse_node_lines(body: bytes, source: str) -> tuple[np.ndarray, np.ndarray]:
    """(n, 34) int64 (parent, leaf flag, 32 descriptor values) and (n,) float64 weights of the node lines.

    ORBvoc.txt has a million lines: numpy parses the integers of all lines at once, and the weights
    (the last field, the only one that is not an integer) are cut out of the text first, looked
    for in a window before each line end. Anything unexpected sends the text to a line-by-line
    check that names the first bad line.
    """
    body = body.rstrip() + b"\n"
    raw = np.frombuffer(body, dtype=np.uint8)
    ends = np.flatnonzero(raw == ord("\n"))
    if body == b"\n":
        raise VocabularyError(f"vocabulary {source}: no nodes after the header: the file is truncated")
    index = np.int32 if raw.size < 2**31 else np.int64  # halves the window's memory for any real file
    back = np.arange(1, _WEIGHT_WINDOW + 1, dtype=index)
    at = np.maximum(ends.astype(index)[:, None] - back, 0)  # (lines, window): the bytes before each line end, last first
    window = raw[at]
    space = (window == ord(" ")) | (window == ord("\r")) | (window == ord("\t"))
    last_char = np.argmax(~space, axis=1)  # skips trailing blanks (and a \r)
    after_weight = space & (back - 1 > last_char[:, None])
    weight_len = np.argmax(after_weight, axis=1) - last_char
    in_weight = (back - 1 >= last_char[:, None]) & (back - 1 < (last_char + weight_len)[:, None])
    lines = ends.size
    if not after_weight.any(axis=1).all() or np.any(raw[ends[:-1] + 1] == ord("\n")):
        raise _first_bad_line(body, source)
    integer_text = raw.copy()
    integer_text[at[in_weight]] = ord(" ")
    weight_text = np.where(in_weight, window, ord(" "))[:, ::-1]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            integers = np.fromstring(integer_text.tobytes(), dtype=np.int64, sep=" ")  # any whitespace separates
            weights = np.array([float(w) for w in weight_text.tobytes().split()], dtype=np.float64)
        except (DeprecationWarning, ValueError):
            raise _first_bad_line(body, source) from None
    if integers.size != lines * (_FIELDS - 1) or weights.size != lines:
        raise _first_bad_line(body, source)
    return integers.reshape(lines, _FIELDS - 1), weights


def _first_bad_line(body: bytes, source: str) -> VocabularyError:
    for number, line in enumerate(body.decode("ascii").split("\n"), start=2):
        fields = line.split()
        if not fields:
            return VocabularyError(f"vocabulary {source}, line {number} is empty: the file is corrupt")
        if len(fields) != _FIELDS:
            values = len(fields) - 3
            hint = (
                f"descriptors of {values} values: zenslam needs 256-bit ORB descriptors ({DESCRIPTOR_BYTES} bytes)"
                + (" (64 values: a SURF vocabulary?)" if values == 64 else "")
                if len(fields) > _FIELDS
                else "the file is truncated or corrupt"
            )
            return VocabularyError(
                f"vocabulary {source}, line {number}: {len(fields)} fields, expected {_FIELDS} (parent, leaf flag, "
                f"{DESCRIPTOR_BYTES} descriptor bytes, weight): {hint}"
            )
        for position, field in enumerate(fields):
            try:
                value = float(field)
            except ValueError:
                return VocabularyError(f"vocabulary {source}, line {number}: {field[:20]!r} is not a number: the file is corrupt")
            if 2 <= position < _FIELDS - 1 and not (value == int(value) and 0 <= value <= 255):
                return VocabularyError(
                    f"vocabulary {source}, line {number}: descriptor value {field[:20]} is not a byte (0-255): zenslam "
                    f"needs 256-bit ORB descriptors ({DESCRIPTOR_BYTES} bytes per node), not float descriptors such as SURF's"
                )
            if position < 2 and value != int(value):
                return VocabularyError(f"vocabulary {source}, line {number}: {field[:20]} is not an integer: the file is corrupt")
    return VocabularyError(f"vocabulary {source}: the node lines cannot be read: the file is corrupt")


def _check_rows(integers: np.ndarray, weights: np.ndarray, source: str) -> None:
    def fail(row: int, problem: str) -> VocabularyError:
        return VocabularyError(f"vocabulary {source}, line {row + 2}: {problem}")

    parent, leaf, descriptor = integers[:, 0], integers[:, 1], integers[:, 2:]
    bad = np.flatnonzero(parent < 0)
    if bad.size:
        raise fail(int(bad[0]), f"parent {parent[bad[0]]} is not a node id: the file is corrupt")
    bad = np.flatnonzero((leaf != 0) & (leaf != 1))
    if bad.size:
        raise fail(int(bad[0]), f"leaf flag {leaf[bad[0]]} is not 0 or 1: the file is corrupt")
    not_byte = (descriptor < 0) | (descriptor > 255)
    bad = np.flatnonzero(not_byte.any(axis=1))
    if bad.size:
        value = descriptor[bad[0]][not_byte[bad[0]]][0]
        raise fail(
            int(bad[0]),
            f"descriptor value {value} is not a byte (0-255): zenslam needs 256-bit ORB descriptors "
            f"({DESCRIPTOR_BYTES} bytes per node)",
        )
    bad = np.flatnonzero(~np.isfinite(weights) | (weights < 0))
    if bad.size:
        raise fail(int(bad[0]), f"weight {weights[bad[0]]} is not a finite, non-negative idf: the file is corrupt")


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
