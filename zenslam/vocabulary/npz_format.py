"""zenslam's own vocabulary file: the tree's arrays in a NumPy .npz (zip), compact and quick to load.

Arrays: ``format`` ("zenslam-vocabulary"), ``version`` (1), ``branching``, ``depth``, ``scoring``
and ``weighting`` (DBoW2's codes: 0 and 0, L1-norm and TF-IDF), ``parents`` (n,) int32 (-1 for the
root), ``descriptors`` (n, 32) uint8, ``weights`` (n,) float64, ``metadata_keys`` and
``metadata_values`` (free text such as the training corpus and command). Entries carry a fixed
timestamp, so the same vocabulary always gives the same bytes.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from zenslam.errors import VocabularyError
from zenslam.vocabulary.dbow2_text import L1_NORM, SCORING_NAMES, TF_IDF, WEIGHTING_NAMES
from zenslam.vocabulary.vocabulary import Vocabulary

FORMAT_NAME = "zenslam-vocabulary"
FORMAT_VERSION = 1
_ARRAYS = ("format", "version", "branching", "depth", "scoring", "weighting", "parents", "descriptors", "weights",
           "metadata_keys", "metadata_values")
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def write_npz(vocabulary: Vocabulary, path: Path) -> None:
    keys = sorted(vocabulary.metadata)
    arrays = {
        "format": np.array(FORMAT_NAME),
        "version": np.array(FORMAT_VERSION),
        "branching": np.array(vocabulary.branching),
        "depth": np.array(vocabulary.depth),
        "scoring": np.array(L1_NORM),
        "weighting": np.array(TF_IDF),
        "parents": vocabulary.parents.astype(np.int32),
        "descriptors": vocabulary.descriptors,
        "weights": vocabulary.weights,
        "metadata_keys": np.array(keys, dtype=np.str_),
        "metadata_values": np.array([vocabulary.metadata[k] for k in keys], dtype=np.str_),
    }
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        for name, array in arrays.items():
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.require(array, requirements='C'), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME), buffer.getvalue(),
                             compress_type=zipfile.ZIP_DEFLATED, compresslevel=9)


def read_npz(data: bytes, source: str) -> Vocabulary:
    """The vocabulary in .npz ``data``; VocabularyError naming ``source`` when it is not a sound one."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            missing = [name for name in _ARRAYS if name not in npz.files]
            if "format" in missing or str(_scalar(npz["format"])) != FORMAT_NAME:
                raise VocabularyError(
                    f"vocabulary {source}: a .npz file but not a zenslam vocabulary (it holds {sorted(npz.files)[:8]}): "
                    "give a file written by 'zenslam vocab train'"
                )
            if missing:
                raise VocabularyError(f"vocabulary {source}: arrays {missing} are missing: the file is corrupt")
            arrays = {name: npz[name] for name in _ARRAYS}
    except VocabularyError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        raise VocabularyError(
            f"vocabulary {source}: cannot be read as a .npz ({exc}): the file is truncated or corrupt; get a complete "
            "copy or train it again with 'zenslam vocab train'"
        ) from None
    header = {name: _scalar(arrays[name]) for name in ("version", "branching", "depth", "scoring", "weighting")}
    if not all(isinstance(value, int) for value in header.values()):
        raise VocabularyError(f"vocabulary {source}: header values {header} are not single integers: the file is corrupt")
    version = header["version"]
    if version != FORMAT_VERSION:
        raise VocabularyError(
            f"vocabulary {source}: format version {version}, this zenslam reads version {FORMAT_VERSION}: "
            "train it again with this version's 'zenslam vocab train'"
        )
    scoring, weighting = header["scoring"], header["weighting"]
    if scoring != L1_NORM or weighting != TF_IDF:
        raise VocabularyError(
            f"vocabulary {source}: scoring code {scoring} and weighting code {weighting}; zenslam uses "
            f"{SCORING_NAMES[L1_NORM]} scoring and {WEIGHTING_NAMES[TF_IDF]} weighting (codes 0 and 0)"
        )
    descriptors = arrays["descriptors"]
    if descriptors.dtype != np.uint8 or descriptors.ndim != 2 or descriptors.shape[1] != 32:
        raise VocabularyError(
            f"vocabulary {source}: node descriptors are {descriptors.dtype} of shape {descriptors.shape}: zenslam needs "
            "256-bit ORB descriptors, (n, 32) uint8"
        )
    metadata = dict(zip(arrays["metadata_keys"].tolist(), arrays["metadata_values"].tolist()))
    return Vocabulary(
        header["branching"], header["depth"], arrays["parents"].astype(np.int64), descriptors,
        arrays["weights"], metadata, source=source,
    )


def _scalar(array: np.ndarray) -> object:
    """The one value of a header array (None when it holds more or fewer; callers then see a wrong value)."""
    return array.reshape(-1)[0].item() if array.size == 1 else None
