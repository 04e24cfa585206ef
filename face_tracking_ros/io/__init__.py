"""Bags and message types without a ROS runtime: the rosbags typestore and bag reading/writing."""
