"""Duplicate keys in a YAML config are an error naming the key and both lines."""

from __future__ import annotations

import pytest

from mercury_dem.config import ConfigError, load_config
from mercury_dem.config.yaml_loader import DuplicateKeyError, safe_load_unique


def test_duplicate_section_names_key_and_lines(tmp_path) -> None:
    cfg = tmp_path / "dup.yaml"
    cfg.write_text("dem:\n  pixels_per_degree: 8\nmatch:\n  ratio: 0.7\ndem:\n  pixels_per_degree: 16\n")
    with pytest.raises(ConfigError) as err:
        load_config(cfg)
    msg = str(err.value)
    assert "'dem'" in msg and "lines 1 and 5" in msg and str(cfg) in msg


def test_duplicate_nested_key(tmp_path) -> None:
    cfg = tmp_path / "dup.yaml"
    cfg.write_text("match:\n  ratio: 0.7\n  ratio: 0.9\n")
    with pytest.raises(ConfigError, match=r"'ratio'.*lines 2 and 3"):
        load_config(cfg)


def test_duplicate_in_flow_mapping_and_equal_keys() -> None:
    with pytest.raises(DuplicateKeyError) as err:
        safe_load_unique("a: {x: 1, y: 2, x: 3}\n")
    assert err.value.key == "x" and err.value.line == 1
    with pytest.raises(DuplicateKeyError):  # 1 and 1.0 are the same dict key
        safe_load_unique("1: a\n1.0: b\n")


def test_same_key_in_different_mappings_and_merges_are_fine(tmp_path) -> None:
    assert safe_load_unique("a: {x: 1}\nb: {x: 2}\n") == {"a": {"x": 1}, "b": {"x": 2}}
    # a merge may be overridden by the mapping's own key, as YAML intends
    assert safe_load_unique("base: &b {x: 1, y: 2}\nc:\n  <<: *b\n  x: 5\n")["c"] == {"x": 5, "y": 2}
    cfg = tmp_path / "ok.yaml"
    cfg.write_text("dem:\n  pixels_per_degree: 16\nmatch:\n  ratio: 0.7\n")
    assert load_config(cfg).dem.pixels_per_degree == 16


def test_safe_loader_still_refuses_python_objects() -> None:
    import yaml

    with pytest.raises(yaml.YAMLError):
        safe_load_unique("a: !!python/object/apply:os.system ['true']\n")
