"""The node parameter tables (docs/parameters.md), the README's node and message tables match."""

from __future__ import annotations

from pathlib import Path
import re

import pytest

from face_tracking_ros.imaging.gray import SUPPORTED_ENCODINGS
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.nodes.reference import BEGIN, END, NODE_CONFIGS, markdown
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.registry import PROCESSORS, processor_factory

README = Path(__file__).resolve().parents[1] / 'README.md'
PARAMETERS = README.parent / 'docs' / 'parameters.md'


def test_node_parameter_tables_are_current():
    text = PARAMETERS.read_text()
    section = text[text.index(BEGIN) : text.index(END) + len(END)]
    assert section == markdown(), (
        'docs/parameters.md is stale: run '
        '`.venv/bin/python -m face_tracking_ros.nodes.reference --write docs/parameters.md`'
    )


def test_every_declared_parameter_has_a_description():
    undocumented = [row for row in markdown().splitlines() if row.endswith('|  |')]
    assert not undocumented, f'parameters without a description: {undocumented}'


class _Recording(OverrideParameters):
    """Defaults, recording the configs a processor reads (not the ones nested in them)."""

    def __init__(self) -> None:
        super().__init__()
        self.read: list[tuple[str, type]] = []
        self._depth = 0

    def config(self, config_type, prefix=''):
        if self._depth == 0:
            self.read.append((prefix, config_type))
        self._depth += 1
        try:
            return super().config(config_type, prefix)
        finally:
            self._depth -= 1


@pytest.mark.parametrize('node', sorted(set(PROCESSORS) & set(NODE_CONFIGS)))
def test_the_tables_list_what_each_processing_node_reads(node):
    parameters = _Recording()
    processor_factory(node)(parameters, RosbagsMessages(typestore()))
    assert tuple(parameters.read) == NODE_CONFIGS[node]


def _node_row(node: str) -> list[str]:
    """The README node table's subscribes, publishes and services cells of a node."""
    (row,) = [line for line in README.read_text().splitlines() if line.startswith(f'| `{node}` |')]
    return row.split(' | ')[1:]


# Each processing node with its default parameters, and the trackers with compressed images.
TOPIC_CASES = [(node, {}) for node in sorted(PROCESSORS)] + [
    (node, {'compressed': 'true'}) for node in ('mono_tracker', 'stereo_tracker')
]


@pytest.mark.parametrize(('node', 'overrides'), TOPIC_CASES)
def test_the_node_table_names_every_topic_a_processing_node_has(node, overrides):
    processor = processor_factory(node)(
        OverrideParameters(overrides), RosbagsMessages(typestore())
    )
    subscribes, publishes, *_ = _node_row(node)
    assert [p.topic for p in processor.inputs if f'`{p.topic}`' not in subscribes] == []
    assert [p.topic for p in processor.outputs if f'`{p.topic}`' not in publishes] == []


def test_the_message_table_lists_every_message_and_service() -> None:
    text = README.read_text()
    start = text.index('| Type | Topic | Content |')
    rows = text[start : text.index('\n\n', start)].splitlines()[2:]
    listed = sorted(row.split('`')[1] for row in rows)
    msg_defs = README.parent / 'msg_defs'
    defined = [p.stem for p in (msg_defs / 'msg').glob('*.msg')]
    defined += [p.name for p in (msg_defs / 'srv').glob('*.srv')]  # listed as Name.srv
    assert listed == sorted(defined)


def test_the_node_table_names_every_image_encoding_the_trackers_read() -> None:
    subscribes, *_ = _node_row('mono_tracker')
    image = subscribes[: subscribes.index('or `image/compressed`')]
    named = re.findall(r'\b(mono8|rgba?8|bgra?8|bayer_\w+8|yuv422\w*|8UC\d)\b', image)
    assert set(named) == set(SUPPORTED_ENCODINGS)
