"""Which typestore reads a type as a bag defines it (face_tracking_ros.io.bag_definitions)."""

from __future__ import annotations

from pathlib import Path

from face_tracking_ros.io.bag_definitions import BagDefinitions
from face_tracking_ros.io.bags import BagWriter, read_raw
from face_tracking_ros.io.typestore import typestore

from message_samples import sample_fields, to_rosbags

STATE = 'face_tracking_msgs/msg/FaceState'
WRITTEN = (STATE, 'sensor_msgs/msg/Image', 'sensor_msgs/msg/CameraInfo')


def test_a_type_the_bag_defines_as_the_package_does_is_read_with_the_package_s(
    tmp_path: Path,
) -> None:
    """The definitions a bag written here holds (ROS 2's text) agree with the package's.

    Compared with ROS 1's text (``time stamp`` for ``builtin_interfaces/Time stamp``), none
    agreed: every read parsed and compiled a store of each type it read.
    """
    store = typestore()
    with BagWriter(tmp_path / 'bag') as bag:
        for index, msgtype in enumerate(WRITTEN):
            message = to_rosbags(store, msgtype, sample_fields(store, msgtype, seed=index))
            bag.write(f'topic_{index}', msgtype, message, index)
    definitions = BagDefinitions(store)
    chosen = {
        raw.msgtype: definitions.store_for(raw.msgtype, raw.msgdef)
        for raw in read_raw(tmp_path / 'bag')
    }
    assert chosen == dict.fromkeys(WRITTEN, store)


def test_a_bag_definition_that_cannot_be_parsed_is_read_with_the_package_s():
    assert BagDefinitions(typestore()).store_for(STATE, 'int32') is typestore()


def test_a_bag_definition_of_other_fields_is_read_with_its_own():
    store = BagDefinitions(typestore()).store_for(STATE, 'float64 x')
    assert store is not typestore()
    assert store.generate_msgdef(STATE)[0] == 'float64 x\n'
