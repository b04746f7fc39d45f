"""Every shell block of the README and the user guide (docs/) is marked and run by a test.

A block is marked by the comment on the line before its fence: ``<!-- readme-command: NAME -->`` in
README.md, ``<!-- docs-command: NAME -->`` (or the README's form) in docs/*.md; files and snippets
that tests read are marked ``docs-python``, ``docs-json5`` or ``docs-yaml`` (``readme-*`` in the
README). ``COMMAND_TESTS`` says which test runs each command block; the helpers here find a block
by its name in whichever of those files holds it, so a block can move between pages freely.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]

# Which test runs each command block (path::function). The README's test command is run by CI
# itself (.ci/run extracts it); its test checks that the extraction gives exactly the README's line.
COMMAND_TESTS = {
    "main": "tests/test_readme.py::test_main_command_on_a_fresh_clone",
    "test": "tests/test_readme.py::test_ci_runs_exactly_the_readme_test_command",
    "tour": "tests/test_readme.py::test_tour_commands_run_in_order",
    "vocab": "tests/test_readme.py::test_vocab_commands_run_in_order",
    "client": "tests/test_readme_client.py::test_readme_pose_logger_receives_every_pose_of_the_run",
    "maps": "tests/integration/test_saved_map.py::test_the_readme_localisation_command_adds_no_keyframe",
    "sources": "tests/test_docs_commands.py::test_sources_commands_run_in_order",
    "config": "tests/test_docs_commands.py::test_config_commands_run_the_documented_yaml",
    "modes": "tests/test_docs_commands.py::test_modes_commands_run_in_order",
    "zenoh-pair": "tests/test_docs_commands.py::test_zenoh_pair_tracks_the_published_clip",
    "ros2-pair": "tests/test_docs_commands.py::test_ros2_pair_tracks_the_published_scene",
    "ros2-echo": "tests/test_docs_commands.py::test_ros2_echo_sees_the_published_poses",
    "machines": "tests/test_docs_commands.py::test_machines_commands_on_loopback",
}

# Which test reads each other marked block (a file or snippet the guide gives).
FILE_TESTS = {
    "pose_logger.py": "tests/test_readme_client.py::test_readme_pose_logger_receives_every_pose_of_the_run",
    "run.yaml": "tests/test_docs_commands.py::test_config_commands_run_the_documented_yaml",
    "machines/run.yaml": "tests/test_docs_commands.py::test_machines_commands_on_loopback",
    **{
        name: "tests/test_readme_zenoh_configs.py::test_readme_zenoh_configs_are_valid"
        for name in ("router.json5", "server.json5", "robot.json5", "router_tls.json5", "robot_tls.json5")
    },
}

_MARKER = re.compile(r"<!-- (readme|docs)-(command|python|json5|yaml): (\S+) -->")
_FENCE = re.compile(r"^```(\w+)\n(.*?)\n```$", re.S | re.M)


@dataclass(frozen=True)
class DocBlock:
    path: Path
    marker: str | None  # "command", "python", "json5" or "yaml"; None when unmarked
    name: str | None
    language: str
    text: str


def doc_files() -> list[Path]:
    return [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]


def doc_blocks() -> list[DocBlock]:
    """Every fenced block of the README and docs/*.md, with the marker on the line before it, if any."""
    blocks = []
    for path in doc_files():
        text = path.read_text()
        for fence in _FENCE.finditer(text):
            before = text[: fence.start()].rstrip("\n").rsplit("\n", 1)[-1]
            marker = _MARKER.fullmatch(before.strip())
            kind, name = (marker.group(2), marker.group(3)) if marker else (None, None)
            if marker and path.name == "README.md" and path.parent == REPO_ROOT:
                assert marker.group(1) == "readme", f"README.md marks a block with {before!r}: use readme-{kind}"
            blocks.append(DocBlock(path, kind, name, fence.group(1), fence.group(2)))
    return blocks


def doc_block(marker: str, name: str) -> str:
    """The text of the one block marked ``<marker>: <name>`` in the README or docs/."""
    found = [b for b in doc_blocks() if b.marker == marker and b.name == name]
    assert len(found) == 1, f"expected one block marked {marker}: {name} in README.md and docs/, found {len(found)}"
    return found[0].text


def doc_command(name: str) -> str:
    """The shell block named ``name`` (``<!-- readme-command: name -->`` or ``<!-- docs-command: name -->``)."""
    return doc_block("command", name).strip()


def command_lines(name: str) -> list[str]:
    """The block's commands, one a line, without comment lines."""
    return [line for line in doc_command(name).splitlines() if line.strip() and not line.lstrip().startswith("#")]


def scratch_checkout(tmp_path: Path, data_root: Path | None = None) -> Path:
    """An empty folder to run commands in as from the repository root, with ``../shared/data`` the real clips."""
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    if data_root is not None:
        (tmp_path / "shared").mkdir()
        (tmp_path / "shared" / "data").symlink_to(data_root)
    return checkout


def command_env() -> dict[str, str]:
    """The environment a user's shell would have: the ``zenslam`` of this interpreter's venv on PATH."""
    env = {"PATH": f"{Path(sys.executable).parent}:/usr/local/bin:/usr/bin:/bin", "HOME": str(Path.home())}
    if "PYTHONPATH" in os.environ:  # a checkout run without installing it (PYTHONPATH=. pytest)
        env["PYTHONPATH"] = os.environ["PYTHONPATH"]
    return env


def run_line(line: str, cwd: Path, timeout_s: float = 900) -> subprocess.CompletedProcess:
    """Run one documented command line with bash in ``cwd``; it must succeed."""
    result = subprocess.run(["bash", "-c", line], cwd=cwd, capture_output=True, text=True, timeout=timeout_s, env=command_env())
    assert result.returncode == 0, f"{line}\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}"
    return result


def test_every_shell_block_is_marked():
    unmarked = [f"{b.path.relative_to(REPO_ROOT)}: {b.text.splitlines()[0]}" for b in doc_blocks() if b.language == "sh" and b.marker != "command"]
    assert not unmarked, f"shell blocks without a <!-- docs-command: NAME --> marker: {unmarked}"


def test_every_marked_block_is_named_once_and_run_by_a_test():
    blocks = [b for b in doc_blocks() if b.marker is not None]
    commands = [b.name for b in blocks if b.marker == "command"]
    files = [b.name for b in blocks if b.marker != "command"]
    assert len(commands) == len(set(commands)), f"command names used twice: {sorted(commands)}"
    assert len(files) == len(set(files)), f"file names used twice: {sorted(files)}"
    assert all(b.language == "sh" for b in blocks if b.marker == "command")
    assert sorted(commands) == sorted(COMMAND_TESTS), "COMMAND_TESTS must name a test for every command block, and no other"
    assert sorted(files) == sorted(FILE_TESTS), "FILE_TESTS must name a test for every marked file block, and no other"


@pytest.mark.parametrize("name", sorted({**COMMAND_TESTS, **FILE_TESTS}))
def test_the_registered_test_exists_and_reads_its_block(name: str):
    test_id = {**COMMAND_TESTS, **FILE_TESTS}[name]
    path, function = test_id.split("::")
    source = (REPO_ROOT / path).read_text()
    assert re.search(rf"^def {function}\(", source, re.M), f"{test_id} does not exist"
    assert f'"{name}"' in source or f"-command: {name} " in source or f": {name}" in source, (
        f"{path} never names the block {name!r}"
    )


def test_the_guide_links_resolve():
    """Relative links between the README, the guide and benchmarks/ point at files that exist."""
    broken = []
    for path in doc_files():
        for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", path.read_text()):
            if not (path.parent / target).exists():
                broken.append(f"{path.relative_to(REPO_ROOT)} -> {target}")
    assert not broken, broken


def test_the_readme_is_a_front_page():
    assert len((REPO_ROOT / "README.md").read_text().splitlines()) <= 200
