"""The vocabulary shipped with zenslam, loaded the first time it is used.

A stage that needs the vocabulary only now and then (the frontend, to relocalise a lost frame)
holds this instead of the loaded vocabulary: the tree and its weights are ~18 MB in memory, which
a run that never loses track never needs. Only the shipped vocabulary is loaded this way: it is
part of the package and cannot be missing or corrupt, whereas a file a user names is loaded at
start, so that a bad one fails the stage before it joins the run.
"""

from __future__ import annotations

import logging

import numpy as np

from zenslam.vocabulary.bow import BowVector, FeatureVector
from zenslam.vocabulary.files import load_vocabulary
from zenslam.vocabulary.vocabulary import Vocabulary

logger = logging.getLogger(__name__)


class ShippedVocabularyOnDemand:
    """``transform`` of the shipped vocabulary, which is loaded at its first call and kept from then on."""

    def __init__(self) -> None:
        self._vocabulary: Vocabulary | None = None

    @property
    def loaded(self) -> bool:
        """True once the vocabulary has been loaded (its first ``transform``)."""
        return self._vocabulary is not None

    def transform(self, descriptors: np.ndarray) -> tuple[BowVector, FeatureVector]:
        """The bag-of-words and feature vectors of ``descriptors`` (N x 32 uint8), as ``Vocabulary.transform``."""
        if self._vocabulary is None:
            self._vocabulary = load_vocabulary(None)
            logger.info("loaded the shipped vocabulary at its first use")
        return self._vocabulary.transform(descriptors)
