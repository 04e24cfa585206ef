"""The README's node parameter tables match the nodes' config dataclasses."""

from __future__ import annotations

from pathlib import Path

from face_tracking_ros.nodes.reference import BEGIN, END, markdown

README = Path(__file__).resolve().parents[1] / 'README.md'


def test_node_parameter_tables_are_current():
    text = README.read_text()
    section = text[text.index(BEGIN) : text.index(END) + len(END)]
    assert section == markdown(), (
        'README node parameters are stale: run '
        '`.venv/bin/python -m face_tracking_ros.nodes.reference --write README.md`'
    )


def test_every_declared_parameter_has_a_description():
    undocumented = [row for row in markdown().splitlines() if row.endswith('|  |')]
    assert not undocumented, f'parameters without a description: {undocumented}'
