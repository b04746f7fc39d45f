"""The bag-of-words vocabulary shared by tracking and mapping: a DBoW2 tree of ORB words, TF-IDF, L1 score.

``load_vocabulary(path)`` reads zenslam's .npz or DBoW2 text (ORB-SLAM's ORBvoc.txt, also .txt.gz);
``load_vocabulary(None)`` the default vocabulary shipped in ``data/``; ``voc.transform(descriptors)``
gives an image's BowVector and FeatureVector, ``voc.score(a, b)`` their similarity.
"""

from zenslam.errors import VocabularyError
from zenslam.vocabulary.bow import BowVector, FeatureVector
from zenslam.vocabulary.files import default_vocabulary_path, load_vocabulary, save_vocabulary
from zenslam.vocabulary.vocabulary import Vocabulary

__all__ = [
    "BowVector",
    "FeatureVector",
    "Vocabulary",
    "VocabularyError",
    "default_vocabulary_path",
    "load_vocabulary",
    "save_vocabulary",
]
