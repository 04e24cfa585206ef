"""The command lines the user documents show use options and node parameters that exist.

README.md, the topic pages under docs/ (all but performance.md, the dated record), DEVELOPERS.md
and bags/README.md show ``face-tracking`` commands whole in ``bash`` blocks and as fragments in
their prose, node command lines with ``-p NAME:=VALUE``, and a parameter file; an option or a
parameter renamed in the code would leave them behind unnoticed.
"""

from __future__ import annotations

import argparse
import re
import shlex

import pytest
import yaml

from face_tracking_ros.cli.main import build_parser
from face_tracking_ros.nodes.reference import NODE_CONFIGS, parameter_rows

from repo_root import REPO

DOCS = (
    'README.md',
    'docs/nodes.md',
    'docs/parameters.md',
    'docs/mono_tracker.md',
    'docs/stereo_tracker.md',
    'docs/recordings.md',
    'docs/benchmarks.md',
    'docs/learning.md',
    'DEVELOPERS.md',
    'bags/README.md',
)
NODE_COMMAND = re.compile(rf'^({"|".join(NODE_CONFIGS)}) --ros-args\b')


RECORD = 'docs/performance.md'  # the dated lab record: commands as they were run then


def test_every_docs_page_is_checked() -> None:
    pages = {f'docs/{page.name}' for page in (REPO / 'docs').glob('*.md')}
    assert pages - {RECORD} <= set(DOCS)


def _text(doc: str) -> str:
    return (REPO / doc).read_text(encoding='utf-8')


def _blocks(text: str, language: str) -> list[str]:
    """The fenced code blocks of one language."""
    return re.findall(rf'^```{language}\n(.*?)^```', text, flags=re.MULTILINE | re.DOTALL)


def _bash_commands(doc: str) -> list[str]:
    """The commands of a document's bash blocks: continuations joined, comments cut."""
    commands = []
    for block in _blocks(_text(doc), 'bash'):
        for line in block.replace('\\\n', ' ').splitlines():
            command = line.split('#')[0].strip()
            if command:
                commands.append(' '.join(command.split()))
    return commands


def _inline_commands(doc: str) -> list[str]:
    """Command fragments in a document's inline code (``face-tracking ...``, a node's)."""
    names = '|'.join(['face-tracking', *NODE_CONFIGS])
    found = re.findall(rf'`((?:{names}) [^`]+)`', _text(doc))
    return [' '.join(fragment.split()) for fragment in found]


def _all_commands() -> list[tuple[str, str]]:
    return [
        (doc, command)
        for doc in DOCS
        for command in [*_bash_commands(doc), *_inline_commands(doc)]
    ]


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _parameters(node: str) -> set[str]:
    return {
        name
        for prefix, config in NODE_CONFIGS[node]
        for name, *_ in parameter_rows(prefix, config)
    }


def test_the_whole_commands_parse() -> None:
    whole = [
        (doc, command)
        for doc in DOCS
        for command in _bash_commands(doc)
        if command.startswith('face-tracking ')
    ]
    assert len(whole) >= 5
    parser = build_parser()
    for doc, command in whole:
        argv = shlex.split(command)[1:]
        if argv == ['--help']:
            continue
        try:
            parser.parse_args(argv)
        except SystemExit:
            pytest.fail(f'{doc}: {command!r} does not parse')


def test_every_option_of_a_fragment_exists() -> None:
    subcommands = _subcommands()
    fragments = [
        (doc, command.split())
        for doc, command in _all_commands()
        if command.startswith('face-tracking ')
    ]
    unknown = []
    for doc, (_, name, *tokens) in fragments:
        if name not in subcommands:  # COMMAND, ...: a placeholder
            continue
        options = {o for action in subcommands[name]._actions for o in action.option_strings}
        for token in tokens:
            option = token.strip('[]').split('=')[0]
            if option.startswith('--') and option not in options:
                unknown.append(f'{doc}: face-tracking {name} {option}')
    assert unknown == []


def test_node_command_lines_set_declared_parameters() -> None:
    lines = [(doc, command) for doc, command in _all_commands() if NODE_COMMAND.match(command)]
    assert {command.split()[0] for _, command in lines} >= {'mono_tracker', 'stereo_tracker'}
    undeclared = []
    for doc, command in lines:
        node = command.split()[0]
        for name in re.findall(r'-p ([\w.]+):=', command):
            if name not in _parameters(node) and not name.startswith('qos_overrides.'):
                undeclared.append(f'{doc}: {node} -p {name}')
    assert undeclared == []


def _flattened(parameters: dict, prefix: str = '') -> list[str]:
    """Dotted names of a parameter file's nested keys."""
    names = []
    for key, value in parameters.items():
        if isinstance(value, dict):
            names += _flattened(value, f'{prefix}{key}.')
        else:
            names.append(prefix + key)
    return names


# A default quoted in prose, its name then its value with a unit: `tracker.fast_motion_px` (4 px a
# frame interval ...), `tracker.epsilon`, 0.2 as in the seed, `occlusion_hold` seconds (2).
QUOTED_DEFAULT = re.compile(
    r'`([a-z_][a-z0-9_.]*)`(?:\s+seconds)?\s*[(,]\s*(-?\d+(?:\.\d+)?)(?:\s+(?:px|s|ms|mm|Hz|degrees))?'
    r'(?=\s*[);]|\s+(?:a|as|in)\s)'
)


def _numeric_defaults() -> dict[str, set[float]]:
    """Every numeric parameter's defaults, over the nodes that declare it."""
    defaults: dict[str, set[float]] = {}
    for configs in NODE_CONFIGS.values():
        for prefix, config in configs:
            for name, default, _ in parameter_rows(prefix, config):
                if re.fullmatch(r'-?\d+(\.\d+)?(e-?\d+)?', default):
                    defaults.setdefault(name, set()).add(float(default))
    return defaults


def test_the_defaults_quoted_in_prose_are_the_codes() -> None:
    defaults = _numeric_defaults()
    quoted = [
        (doc, name, float(value))
        for doc in DOCS
        for name, value in QUOTED_DEFAULT.findall(' '.join(_text(doc).split()))
        if name in defaults
    ]
    assert len(quoted) >= 10  # the pattern still finds them
    assert [q for q in quoted if q[2] not in defaults[q[1]]] == []


def test_parameter_files_name_declared_parameters() -> None:
    files = [
        yaml.safe_load(block)
        for doc in DOCS
        for block in _blocks(_text(doc), 'yaml')
        if 'ros__parameters' in block
    ]
    assert files
    for content in files:
        for node, section in content.items():
            assert set(_flattened(section['ros__parameters'])) <= _parameters(node)


def test_the_command_table_lists_every_subcommand() -> None:
    text = _text('README.md')
    start = text.index('### Command-line tools')
    table = text[start : text.index('\n\n', text.index('| command |', start))]
    listed = set(re.findall(r'^\| `([a-z-]+)[ `]', table, flags=re.MULTILINE))
    listed |= set(re.findall(r'/ `([a-z-]+) ', table))  # `plot OUT ...` / `overlay BAG ...`
    assert listed == set(_subcommands())
