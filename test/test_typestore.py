"""Where the typestore finds the face_tracking_msgs .msg text (io.typestore.msg_dir)."""

from __future__ import annotations

from pathlib import Path

from ament_index_python.packages import get_package_share_directory
import pytest

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io import typestore as typestore_module
from face_tracking_ros.io.typestore import msg_dir

from repo_root import REPO


def test_the_msg_files_are_the_installed_package_s():
    installed = get_package_share_directory('face_tracking_msgs')
    assert msg_dir() == Path(installed) / 'msg'
    assert msg_dir() != REPO / 'msg_defs' / 'msg'


def test_without_an_installed_package_the_msg_files_are_the_source_tree_s(monkeypatch):
    monkeypatch.setattr(typestore_module, '_installed_msg_dir', lambda: None)
    assert msg_dir() == REPO / 'msg_defs' / 'msg'


def test_without_either_the_error_names_both_places(monkeypatch, tmp_path):
    monkeypatch.setattr(typestore_module, '_installed_msg_dir', lambda: None)
    monkeypatch.setattr(typestore_module, 'SOURCE_MSG_DIR', tmp_path / 'msg')
    with pytest.raises(ConfigError) as error:
        msg_dir()
    assert str(error.value) == (
        'cannot find the face_tracking_msgs .msg files: neither installed (ament index, '
        f'AMENT_PREFIX_PATH) nor in the source tree at {tmp_path / "msg"}'
    )
