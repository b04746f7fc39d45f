"""Vocabulary files: zenslam's .npz and DBoW2 text (ORBvoc.txt, .txt.gz) both ways, and errors naming file and problem."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
from vocabulary_helpers import full_tree, random_descriptors

from zenslam.errors import VocabularyError
from zenslam.vocabulary import Vocabulary, load_vocabulary, save_vocabulary
from zenslam.vocabulary.dbow2_text import format_dbow2_text


@pytest.fixture(scope="module")
def vocabulary() -> Vocabulary:
    rng = np.random.default_rng(30)
    weights = np.log(rng.uniform(1.0, 50.0, size=1 + 3 + 9 + 27))  # idf-like, with many digits
    tree = full_tree(rng, 3, 3, weights)
    return Vocabulary(3, 3, tree.parents, tree.descriptors, tree.weights, {"corpus": "synthetic\nstrings"})


def assert_same(a: Vocabulary, b: Vocabulary) -> None:
    assert (a.branching, a.depth, a.n_words) == (b.branching, b.depth, b.n_words)
    for name in ("parents", "descriptors", "weights"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


@pytest.mark.parametrize("name", ["voc.npz", "voc.txt", "voc.txt.gz"])
def test_round_trip_keeps_the_tree_and_the_transforms(vocabulary, tmp_path: Path, name: str):
    loaded = load_vocabulary(save_vocabulary(vocabulary, tmp_path / name))
    assert_same(vocabulary, loaded)
    descriptors = random_descriptors(np.random.default_rng(31), 100)
    (bow_a, fvec_a), (bow_b, fvec_b) = vocabulary.transform(descriptors), loaded.transform(descriptors)
    assert np.array_equal(bow_a.word_ids, bow_b.word_ids) and np.array_equal(bow_a.weights, bow_b.weights)
    assert np.array_equal(fvec_a.node_ids, fvec_b.node_ids)
    if name.endswith(".npz"):
        assert loaded.metadata == {"corpus": "synthetic\nstrings"}


def test_ours_to_dbow2_text_and_back_is_the_same(vocabulary, tmp_path: Path):
    text = save_vocabulary(vocabulary, tmp_path / "ORBvoc.txt")
    again = load_vocabulary(save_vocabulary(load_vocabulary(text), tmp_path / "again.npz"))
    assert_same(vocabulary, again)
    assert save_vocabulary(again, tmp_path / "again.txt").read_bytes() == text.read_bytes()


def test_text_is_what_dbow2_save_to_text_file_writes(vocabulary):
    lines = format_dbow2_text(vocabulary).splitlines()
    assert lines[0] == "3 3  0 0"
    assert len(lines) == vocabulary.n_nodes  # one line per node after the root
    fields = lines[5].split()  # node 5: a child of node 1, not a leaf
    assert len(fields) == 35 and fields[:2] == ["1", "0"]
    assert [int(f) for f in fields[2:34]] == vocabulary.descriptors[5].tolist()
    leaf = lines[20].split()
    assert leaf[1] == "1" and float(leaf[34]) == vocabulary.weights[20]


def test_a_hand_written_orbvoc_style_file_loads(tmp_path: Path):
    zeros, ones = " ".join(["0"] * 32), " ".join(["255"] * 32)
    path = tmp_path / "tiny.txt"
    path.write_text(f"10 2  0 0\n0 0 {zeros} 0\n0 1 {ones} 0.5\n1 1 {zeros} 1.25\n1 1 {ones.replace('255', '15')} 2\n")
    vocabulary = load_vocabulary(path)
    assert vocabulary.n_nodes == 5 and vocabulary.n_words == 3  # words: nodes 2, 3, 4 in node order
    assert vocabulary.word_weights.tolist() == [0.5, 1.25, 2.0]
    assert vocabulary.words(np.zeros((1, 32), np.uint8)).tolist() == [1]


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def node_line(parent: int, leaf: int, values: list, weight: str = "0.5") -> str:
    return f"{parent} {leaf} {' '.join(str(v) for v in values)} {weight}\n"


def test_missing_folder_empty_and_unknown_files_name_the_file_and_what_to_do(tmp_path: Path):
    cases = [
        (tmp_path / "nowhere.txt", "does not exist: name a zenslam .npz vocabulary or a DBoW2 text one"),
        (tmp_path, "is a folder"),
        (write(tmp_path / "empty.txt", ""), "is empty"),
        (write(tmp_path / "yaml.yml", "%YAML:1.0\nvocabulary:\n"), "OpenCV YAML"),
        (write(tmp_path / "words.txt", "hello world\n"), "is not DBoW2's 'k L scoring weighting'"),
    ]
    (tmp_path / "binary.bin").write_bytes(bytes(range(256)))
    cases.append((tmp_path / "binary.bin", "not a text file"))
    for path, message in cases:
        with pytest.raises(VocabularyError, match=message) as error:
            load_vocabulary(path)
        assert str(path) in str(error.value)


def test_truncated_files_are_reported_as_truncated(vocabulary, tmp_path: Path):
    text = format_dbow2_text(vocabulary)
    cut_mid_line = write(tmp_path / "mid.txt", text[: len(text) // 2])
    with pytest.raises(VocabularyError, match=r"mid.txt, line \d+: \d+ fields, expected 35 .* truncated or corrupt"):
        load_vocabulary(cut_mid_line)
    lines = text.splitlines(keepends=True)
    cut_at_line = write(tmp_path / "lines.txt", "".join(lines[:8]))  # nodes 1..7: node 3 loses its children (10..12)
    with pytest.raises(VocabularyError, match=r"lines.txt, line 4: node 3 is marked as an inner node but has no children"):
        load_vocabulary(cut_at_line)
    gz = save_vocabulary(vocabulary, tmp_path / "voc.txt.gz")
    gz.write_bytes(gz.read_bytes()[:-40])
    with pytest.raises(VocabularyError, match="voc.txt.gz: gzip data cannot be decompressed"):
        load_vocabulary(gz)
    npz = save_vocabulary(vocabulary, tmp_path / "voc.npz")
    npz.write_bytes(npz.read_bytes()[:1000])
    with pytest.raises(VocabularyError, match="voc.npz: cannot be read as a .npz .* truncated or corrupt"):
        load_vocabulary(npz)


def test_vocabularies_of_other_descriptors_are_refused(tmp_path: Path):
    surf = write(tmp_path / "surf.txt", "10 2  0 0\n" + node_line(0, 1, [0.25] * 64))
    with pytest.raises(VocabularyError, match="surf.txt, line 2: 67 fields.*64 values: a SURF vocabulary"):
        load_vocabulary(surf)
    floats = write(tmp_path / "floats.txt", "10 2  0 0\n" + node_line(0, 1, [0.25] * 32))
    with pytest.raises(VocabularyError, match="floats.txt, line 2: descriptor value 0.25 is not a byte"):
        load_vocabulary(floats)
    short = write(tmp_path / "short.txt", "10 2  0 0\n" + node_line(0, 1, [7] * 16))
    with pytest.raises(VocabularyError, match="short.txt, line 2: 19 fields, expected 35"):
        load_vocabulary(short)
    big = write(tmp_path / "big.txt", "10 2  0 0\n" + node_line(0, 1, [300] * 32))
    with pytest.raises(VocabularyError, match="big.txt, line 2: descriptor value 300 is not a byte"):
        load_vocabulary(big)


@pytest.mark.parametrize(
    ("header", "message"),
    [
        ("10 6  1 0", r"scoring code 1 \(L2-norm\) is not supported"),
        ("10 6  0 2", r"weighting code 2 \(idf\) is not supported"),
        ("10 6  9 0", r"scoring code 9 \(unknown\)"),
        ("10 6  0 7", r"weighting code 7 \(unknown\)"),
        ("30 6  0 0", r"k=30, L=6 out of DBoW2's range"),
    ],
)
def test_unsupported_scoring_weighting_and_shape_codes(tmp_path: Path, header: str, message: str):
    path = write(tmp_path / "codes.txt", header + "\n" + node_line(0, 1, [1] * 32))
    with pytest.raises(VocabularyError, match=message):
        load_vocabulary(path)


def test_a_npz_that_is_not_a_vocabulary_and_an_unknown_output_name(vocabulary, tmp_path: Path):
    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    with pytest.raises(VocabularyError, match="other.npz: a .npz file but not a zenslam vocabulary"):
        load_vocabulary(other)
    with pytest.raises(VocabularyError, match=r"end it in .npz .* or .txt / .txt.gz"):
        save_vocabulary(vocabulary, tmp_path / "voc.bin")


def test_files_are_reproducible(vocabulary, tmp_path: Path):
    for name in ("a.npz", "a.txt.gz"):
        first = save_vocabulary(vocabulary, tmp_path / name).read_bytes()
        assert save_vocabulary(vocabulary, tmp_path / f"b{name}").read_bytes() == first
    assert gzip.decompress(first).decode().startswith("3 3  0 0\n")


def test_crlf_trailing_blanks_and_any_float_notation_read_the_same(vocabulary, tmp_path: Path):
    zeros, ones = " ".join(["0"] * 32), " ".join(["255"] * 32)
    lines = ["10 2  0 0", f"0 0 {zeros} 0", f"0 1 {ones} 2.5e-1", f"1 1 {zeros} 1.2500000000000000000", f"1 1 {ones} 3"]
    plain = load_vocabulary(write(tmp_path / "plain.txt", "\n".join(lines) + "\n"))
    messy = load_vocabulary(write(tmp_path / "messy.txt", "\r\n".join(line + "  " for line in lines) + "\r\n\r\n"))
    assert_same(plain, messy)
    assert plain.word_weights.tolist() == [0.25, 1.25, 3.0]
    blank_inside = write(tmp_path / "blank.txt", "\n".join([*lines[:3], "", *lines[3:]]) + "\n")
    with pytest.raises(VocabularyError, match=r"blank.txt, line 4 is empty"):
        load_vocabulary(blank_inside)


def test_a_npz_of_other_descriptors_or_codes_is_refused(vocabulary, tmp_path: Path):
    path = save_vocabulary(vocabulary, tmp_path / "voc.npz")
    arrays = dict(np.load(path))
    float_descriptors = tmp_path / "surf.npz"
    np.savez(float_descriptors, **{**arrays, "descriptors": np.zeros((vocabulary.n_nodes, 64), np.float32)})
    with pytest.raises(VocabularyError, match=r"surf.npz: node descriptors are float32 of shape .* 256-bit ORB"):
        load_vocabulary(float_descriptors)
    l2 = tmp_path / "l2.npz"
    np.savez(l2, **{**arrays, "scoring": np.array(1)})
    with pytest.raises(VocabularyError, match="l2.npz: scoring code 1 and weighting code 0"):
        load_vocabulary(l2)
