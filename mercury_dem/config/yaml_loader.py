"""YAML reading for configuration files: PyYAML's SafeLoader, refusing duplicate keys.

PyYAML (like the YAML 1.1 it implements) lets the last of two equal keys in a
mapping win without a word, so a config with ``dem:`` twice silently drops the
first section. :class:`UniqueKeySafeLoader` is ``yaml.SafeLoader`` (no object
construction) with one check added before each mapping is built; it is written
here because PyYAML has no option for it and a second YAML library (ruamel)
would be a new dependency for one check. Keys brought in by a merge (``<<: *a``)
may still be overridden by the mapping's own keys, as YAML intends.
"""

from __future__ import annotations

from typing import Any

import yaml
from yaml.constructor import ConstructorError

_MERGE_TAG = "tag:yaml.org,2002:merge"


class DuplicateKeyError(ConstructorError):
    """A mapping holds the same key twice; ``key``, ``line`` and ``first_line`` (1-based) say where."""

    def __init__(self, key: Any, line: int, first_line: int, node: yaml.MappingNode, key_node: yaml.Node) -> None:
        super().__init__("while constructing a mapping", node.start_mark,
                         f"found duplicate key {key!r} (first defined on line {first_line})", key_node.start_mark)
        self.key = key
        self.line = line
        self.first_line = first_line


class UniqueKeySafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that raises :class:`DuplicateKeyError` on a repeated mapping key."""

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE_TAG:
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.get(key)
                except TypeError:  # an unhashable key: the base class raises its own error for it
                    continue
                line = key_node.start_mark.line + 1
                if first is not None:
                    raise DuplicateKeyError(key, line, first, node, key_node)
                seen[key] = line
        return super().construct_mapping(node, deep=deep)


def safe_load_unique(text: str) -> Any:
    """Parse one YAML document like ``yaml.safe_load``, but a duplicate key raises :class:`DuplicateKeyError`."""
    return yaml.load(text, Loader=UniqueKeySafeLoader)  # noqa: S506 - a SafeLoader subclass
