"""Loading and saving vocabularies: zenslam's .npz or DBoW2 text (ORBvoc.txt, also .txt.gz), and the default one."""

from __future__ import annotations

import gzip
import logging
import time
import zlib
from importlib import resources
from pathlib import Path

from zenslam.errors import VocabularyError
from zenslam.vocabulary.dbow2_text import parse_dbow2_text, write_dbow2_text
from zenslam.vocabulary.npz_format import read_npz, write_npz
from zenslam.vocabulary.vocabulary import Vocabulary

logger = logging.getLogger(__name__)

DEFAULT_VOCABULARY = "orb_k10_L5.npz"  # in zenslam/vocabulary/data/; its corpus is described in data/README.md
_GZIP_MAGIC = b"\x1f\x8b"
_ZIP_MAGIC = b"PK\x03\x04"


def default_vocabulary_path() -> Path:
    """The vocabulary shipped with the package."""
    return Path(str(resources.files("zenslam.vocabulary").joinpath("data", DEFAULT_VOCABULARY)))


def load_vocabulary(path: str | Path | None = None) -> Vocabulary:
    """The vocabulary in ``path`` (None: the default one), whatever its format: told apart by content.

    Raises VocabularyError naming the file and the problem: missing, unreadable, truncated or
    corrupt, not of 256-bit ORB descriptors, or not scored with L1 / weighted with TF-IDF.
    """
    file = default_vocabulary_path() if path is None else Path(path).expanduser()
    source = str(file)
    start = time.perf_counter()
    try:
        data = file.read_bytes()
    except FileNotFoundError:
        raise VocabularyError(
            f"vocabulary {source} does not exist: name a zenslam .npz vocabulary or a DBoW2 text one such as "
            "ORB-SLAM's ORBvoc.txt (or leave the setting empty for the default vocabulary)"
        ) from None
    except IsADirectoryError:
        raise VocabularyError(f"vocabulary {source} is a folder: name the vocabulary file in it") from None
    except OSError as exc:
        raise VocabularyError(f"vocabulary {source} cannot be read: {exc.strerror or exc}") from None
    if data.startswith(_GZIP_MAGIC):
        try:
            data = gzip.decompress(data)
        except (EOFError, OSError, zlib.error) as exc:
            raise VocabularyError(
                f"vocabulary {source}: gzip data cannot be decompressed ({exc}): the file is truncated or corrupt; "
                "get a complete copy"
            ) from None
    if data.startswith(_ZIP_MAGIC):
        vocabulary = read_npz(data, source)
    elif data.lstrip().startswith(b"%YAML"):
        raise VocabularyError(
            f"vocabulary {source}: an OpenCV YAML (DBoW2 'save') vocabulary, which zenslam does not read: convert it "
            "to DBoW2 text (ORB-SLAM's saveToTextFile) or train one with 'zenslam vocab train'"
        )
    elif not data.strip():
        raise VocabularyError(f"vocabulary {source} is empty: get a complete copy or train one with 'zenslam vocab train'")
    else:
        vocabulary = parse_dbow2_text(data, source)
    logger.debug("loaded %r in %.2f s", vocabulary, time.perf_counter() - start)
    return vocabulary


def save_vocabulary(vocabulary: Vocabulary, path: str | Path) -> Path:
    """Write the vocabulary in the format its name asks for: .npz (zenslam) or .txt / .txt.gz (DBoW2 text)."""
    file = Path(path).expanduser()
    name = file.name.lower()
    if not name.endswith((".npz", ".txt", ".txt.gz")):
        raise VocabularyError(
            f"cannot tell the format of {file} from its name: end it in .npz (zenslam's compact format) or "
            ".txt / .txt.gz (DBoW2 text, what ORB-SLAM2/3 load)"
        )
    try:
        if name.endswith(".npz"):
            write_npz(vocabulary, file)
        else:
            write_dbow2_text(vocabulary, file)
    except OSError as exc:
        raise VocabularyError(f"cannot write vocabulary {file}: {exc.strerror or exc}") from None
    return file
