"""The repository's root directory, for the tests that read its bags, config and files.

A module of its own, not conftest.py: test files import it by a name no other directory's
conftest.py shares, so any order of test files works.
"""

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
