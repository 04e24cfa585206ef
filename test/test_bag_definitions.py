"""Which typestore reads a type as a bag defines it (face_tracking_ros.io.bag_definitions)."""

from __future__ import annotations

from face_tracking_ros.io.bag_definitions import BagDefinitions
from face_tracking_ros.io.typestore import typestore

STATE = 'face_tracking_msgs/msg/FaceState'


def test_a_type_the_bag_defines_as_the_package_does_is_read_with_the_package_s():
    definition = typestore().generate_msgdef(STATE)[0]
    assert BagDefinitions(typestore()).store_for(STATE, definition) is typestore()


def test_a_bag_definition_that_cannot_be_parsed_is_read_with_the_package_s():
    assert BagDefinitions(typestore()).store_for(STATE, 'int32') is typestore()


def test_a_bag_definition_of_other_fields_is_read_with_its_own():
    store = BagDefinitions(typestore()).store_for(STATE, 'float64 x')
    assert store is not typestore()
    assert store.generate_msgdef(STATE)[0] == 'float64 x\n'
