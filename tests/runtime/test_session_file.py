"""session.json: how a program outside a run finds its session and hub endpoint."""

from __future__ import annotations

import pytest

from zenslam.errors import ConfigError
from zenslam.runtime.session_file import SESSION_FILENAME, SessionInfo, read_session_file, write_session_file


def test_the_session_file_reads_back_what_was_written(tmp_path):
    info = SessionInfo("demo", ("tcp/127.0.0.1:7447",))
    assert write_session_file(tmp_path, info) == tmp_path / SESSION_FILENAME
    assert read_session_file(tmp_path) == info


def test_a_missing_session_file_names_the_folder(tmp_path):
    with pytest.raises(ConfigError, match=rf"{tmp_path}.*session.json does not exist"):
        read_session_file(tmp_path, timeout_s=0.05)


def test_a_file_that_is_not_a_session_file_is_refused(tmp_path):
    (tmp_path / SESSION_FILENAME).write_text('{"connect": []}')
    with pytest.raises(ConfigError, match="not a zenslam session file"):
        read_session_file(tmp_path)
