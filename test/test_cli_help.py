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
