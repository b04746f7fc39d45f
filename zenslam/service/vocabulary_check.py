"""A run's bag-of-words vocabularies, checked before any of its stages starts.

The backend loads ``backend.vocabulary`` for place recognition, and the frontend
``frontend.vocabulary`` to relocalise (when relocalisation is on); a file that is missing or
corrupt would stop that stage only once it has started, after the others. ``zenslam run`` reads
each named file here first, as the stages will, so that a bad one ends the run before any process
starts, with the error of ``zenslam.vocabulary.load_vocabulary`` (the file and what to do) under
the name of the setting. The vocabulary shipped with zenslam (an empty setting) is part of the
package and is not read again here.
"""

from __future__ import annotations

from zenslam.errors import VocabularyError
from zenslam.service.run_config import RunConfig


def vocabulary_settings(config: RunConfig) -> dict[str, str]:
    """The run's settings that name a vocabulary file its stages load: setting -> path."""
    settings = {"backend.vocabulary": config.backend.vocabulary}
    if config.frontend.tracking.relocalisation.enabled:
        settings["frontend.vocabulary"] = config.frontend.vocabulary or ""
    return {setting: path for setting, path in settings.items() if path}


def check_vocabularies(config: RunConfig) -> None:
    """Read every vocabulary file the run's stages will load; VocabularyError naming the setting, the
    file and what to do when one is missing, unreadable or corrupt. A file named twice is read once."""
    from zenslam.vocabulary import load_vocabulary

    checked: set[str] = set()
    for setting, path in vocabulary_settings(config).items():
        if path in checked:
            continue
        try:
            load_vocabulary(path)
        except VocabularyError as exc:
            raise VocabularyError(f"{setting}: {exc}") from None
        checked.add(path)
