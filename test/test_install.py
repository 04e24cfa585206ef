"""The venv prefix is an ament prefix holding face_tracking_ros, as `ros2 run` needs it.

`ros2 run PKG EXE` runs ``get_package_prefix(PKG)/lib/PKG/EXE``; tools/ament_prefix.py writes
those files in `make setup` (pip's editable install does not).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
import subprocess
import sys
from types import ModuleType

from ament_index_python.packages import get_package_prefix, get_package_share_directory
import pytest

from repo_root import REPO

PACKAGE = 'face_tracking_ros'


def load_ament_prefix_tool() -> ModuleType:
    """Import tools/ament_prefix.py, which reads the entry points of setup.py."""
    spec = importlib.util.spec_from_file_location(
        'ament_prefix', REPO / 'tools' / 'ament_prefix.py'
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


TOOL = load_ament_prefix_tool()
NODES = TOOL.read_entry_points(REPO / 'setup.py', ('NODES',))
EXECUTABLES = TOOL.read_entry_points(REPO / 'setup.py')


def executable(name: str) -> Path:
    """Where `ros2 run face_tracking_ros NAME` looks."""
    return Path(get_package_prefix(PACKAGE)) / 'lib' / PACKAGE / name


def test_package_prefix_resolves_to_the_venv() -> None:
    prefix = Path(get_package_prefix(PACKAGE))

    assert prefix.resolve() == Path(sys.prefix).resolve()
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()


def test_share_holds_package_xml_and_dds_profile() -> None:
    share = Path(get_package_share_directory(PACKAGE))

    assert (share / 'package.xml').read_text() == (REPO / 'package.xml').read_text()
    assert (share / 'config' / 'fastdds_profile.xml').is_file()


def test_interface_package_is_installed() -> None:
    share = Path(get_package_share_directory('face_tracking_msgs'))

    assert sorted(p.name for p in (share / 'msg').glob('*.msg')) == sorted(
        p.name for p in (REPO / 'msg_defs' / 'msg').glob('*.msg')
    )


@pytest.mark.parametrize('name', [*sorted(NODES), 'face-tracking'])
def test_executable_is_installed_for_ros2_run(name: str) -> None:
    path = executable(name)

    assert path.is_file(), f'{path} missing: run make setup'
    assert path.stat().st_mode & 0o111, f'{path} is not executable'
    assert f'from {EXECUTABLES[name].split(":")[0]} import' in path.read_text()


def test_face_tracking_command_runs_from_the_ament_prefix() -> None:
    result = subprocess.run(
        [str(executable('face-tracking')), '--help'], capture_output=True, text=True, timeout=60
    )

    assert result.returncode == 0, result.stderr
    assert 'usage: face-tracking' in result.stdout


def test_the_readme_node_table_lists_every_node_executable() -> None:
    text = (REPO / 'README.md').read_text(encoding='utf-8')
    start = text.index('| node | subscribes | publishes | services |')
    rows = text[start : text.index('\n\n', start)].splitlines()[2:]
    assert sorted(row.split('`')[1] for row in rows) == sorted(NODES)
