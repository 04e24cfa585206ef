"""The package's YAML parser: PyYAML's safe loader, on libyaml where PyYAML was built with it.

Every bag open parses the bag's ``metadata.yaml`` (the files it lists, its topics, its custom
data); libyaml's ``CSafeLoader`` does it in 0.34 ms where the pure-Python ``SafeLoader`` takes
2.76 ms (a sample stereo bag's, 1.9 kB), which makes the whole open 9.0 -> 6.4 ms. Both build
the same values (the same safe constructor and resolver); where libyaml refuses a text, the
pure-Python parser decides, so a malformed file is named by its message, which quotes the
offending character (e.g. a tab) where libyaml's does not.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

import yaml
from yaml.constructor import ConstructorError

_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)  # libyaml's, where PyYAML has it


def parse_yaml(text: str) -> Any:
    """The value of a YAML document (safe loader: plain types only, no object tags).

    Raises:
        yaml.YAMLError: for malformed YAML, with the pure-Python parser's message.
    """
    try:
        return yaml.load(text, Loader=_LOADER)
    except yaml.YAMLError:
        return yaml.load(text, Loader=yaml.SafeLoader)  # its value, or its error message


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that gives a key twice (it keeps the last)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        """The mapping of ``node``; raises ConstructorError naming a key it gives twice.

        An unhashable key (a list) is left to PyYAML's own check, which names it.
        """
        seen: set[Hashable] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, Hashable):
                break
            if key in seen:
                msg = f'found key {key!r} twice'
                raise ConstructorError(
                    'while constructing a mapping', node.start_mark, msg, key_node.start_mark
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def parse_yaml_unique_keys(text: str) -> Any:
    """The value of a YAML document typed by hand, where a key given twice is a mistake.

    As :func:`parse_yaml` (its pure-Python parser: such files are small), but a mapping that
    gives a key twice is refused where PyYAML keeps the last value (e.g. a node clicked twice).

    Raises:
        yaml.YAMLError: for malformed YAML or a key given twice, naming the line.
    """
    return yaml.load(text, Loader=_UniqueKeyLoader)
