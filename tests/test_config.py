"""Typed configs from YAML mappings: a section that is not a mapping is a ConfigError naming the section."""

from __future__ import annotations

import types
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from zenslam.config import from_mapping
from zenslam.errors import ConfigError
from zenslam.runtime.stage import load_section
from zenslam.service.run_config import load_run_config


@dataclass(frozen=True)
class Inner:
    rate_hz: float = 10.0  # Hz


@dataclass(frozen=True)
class Outer:
    name: str = "outer"
    inner: Inner = field(default_factory=Inner)


@pytest.mark.parametrize("value", [[1, 2], [["rate_hz", 5.0]], [], "rate_hz: 5", 5], ids=["list", "pairs", "empty-list", "str", "int"])
def test_a_section_that_is_not_a_mapping_names_the_section(value):
    with pytest.raises(ConfigError, match=r"^'outer' must be a mapping of keys to values \(`key: value` lines\), got a "):
        from_mapping(Outer, value, "outer")


def test_without_a_section_name_the_class_is_named():
    with pytest.raises(ConfigError, match=r"^'Outer' must be a mapping .*got a list: \[1\]"):
        from_mapping(Outer, [1])


def test_an_empty_section_takes_the_defaults_and_any_mapping_is_read():
    assert from_mapping(Outer, None, "outer") == Outer()
    assert from_mapping(Outer, {}, "outer") == Outer()
    read = from_mapping(Outer, types.MappingProxyType({"inner": {"rate_hz": 5}}), "outer")
    assert read == Outer(inner=Inner(rate_hz=5.0))


def test_a_nested_section_that_is_not_a_mapping_names_its_path():
    with pytest.raises(ConfigError, match=r"'outer\.inner' must be a mapping"):
        from_mapping(Outer, {"inner": [1, 2]}, "outer")


def test_a_stage_section_given_as_a_list_names_the_section(tmp_path: Path):
    from zenslam.runtime.bus import BusConfig

    path = tmp_path / "config.yaml"
    path.write_text("bus:\n  - listen\n  - connect\n")
    with pytest.raises(ConfigError, match=r"^'bus' must be a mapping .*got a list: \['listen', 'connect'\]"):
        load_section(path, "bus", BusConfig)


def test_a_run_config_section_given_as_a_list_names_the_section(tmp_path: Path):
    path = tmp_path / "config.yaml"
    path.write_text("source:\n  - synthetic\n")
    with pytest.raises(ConfigError, match=r"'source' must be a mapping"):
        load_run_config(path)


def test_a_resolved_run_config_reads_back_the_same_with_libyaml_as_with_pure_python(tmp_path: Path):
    import yaml

    from zenslam.config import load_yaml
    from zenslam.service.run_config import RunConfig, run_config_to_yaml

    text = run_config_to_yaml(RunConfig())
    path = tmp_path / "config.yaml"
    path.write_text(text)
    assert load_yaml(path) == yaml.load(text, Loader=yaml.SafeLoader)


def test_a_config_file_that_is_not_yaml_is_named(tmp_path: Path):
    from zenslam.config import load_yaml

    path = tmp_path / "config.yaml"
    path.write_text("frontend: [unclosed\n")
    with pytest.raises(ConfigError, match=r"config\.yaml is not valid YAML"):
        load_yaml(path)
