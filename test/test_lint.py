"""ruff (configured in pyproject.toml to agree with ament_flake8) passes over the code."""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import pytest

from repo_root import REPO

RUFF = Path(sys.executable).parent / 'ruff'
PATHS = ['face_tracking_ros', 'test', 'tools', 'setup.py']


@pytest.mark.parametrize('command', [['check'], ['format', '--check', '--diff']])
def test_ruff(command: list[str]) -> None:
    result = subprocess.run(
        [str(RUFF), *command, *PATHS], cwd=REPO, capture_output=True, text=True, timeout=120
    )

    assert result.returncode == 0, f'ruff {" ".join(command)}:\n{result.stdout}{result.stderr}'
