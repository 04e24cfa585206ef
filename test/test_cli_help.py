"""Every ``face-tracking`` subcommand's --help: plain text, and every option explained."""

from __future__ import annotations

import argparse

import pytest

from face_tracking_ros.cli.main import build_parser


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


@pytest.mark.parametrize('name', sorted(_subcommands()))
def test_help_is_plain_text_and_explains_every_option(name: str) -> None:
    parser = _subcommands()[name]
    text = parser.format_help()
    assert '``' not in text  # reST markup of a module docstring shown raw
    unexplained = [
        action.option_strings or [action.dest]
        for action in parser._actions
        if not action.help and not isinstance(action, argparse._HelpAction)
    ]
    assert unexplained == []


def test_a_description_from_the_module_docstring_is_its_summary() -> None:
    """The enroll and demo help texts: a paragraph of their module's docstring."""
    parsers = _subcommands()
    enroll, demo = (' '.join(parsers[name].format_help().split()) for name in ('enroll', 'demo'))
    assert "The offline counterpart of the identity_recognizer's enroll_identity service" in enroll
    assert 'face-tracking demo --out DIR: the whole system, end to end, on the synthetic' in demo


def test_synth_renders_the_size_its_help_states_by_default() -> None:
    parser = _subcommands()['synth']
    assert '(640x480)' in ' '.join(parser.format_help().split())
    assert parser.parse_args([]).size == (640, 480)
