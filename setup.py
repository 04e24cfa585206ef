"""Setup script of the ament_python package face_tracking_ros.

Console scripts go to ``lib/face_tracking_ros`` (see setup.cfg) so ``ros2 run face_tracking_ros
<node>`` finds them in a colcon workspace. Add a node by adding one line to ``NODES``; in the venv,
``make setup`` (tools/ament_prefix.py) mirrors the same executables into the venv prefix.
"""

from __future__ import annotations

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'face_tracking_ros'

# ROS node executables: script name -> 'module:function'. One entry per node.
NODES: dict[str, str] = {
    'mono_tracker': 'face_tracking_ros.nodes.mono_tracker:main',
    'stereo_tracker': 'face_tracking_ros.nodes.stereo_tracker:main',
    'expression_recognizer': 'face_tracking_ros.nodes.expression_recognizer:main',
    'identity_recognizer': 'face_tracking_ros.nodes.identity_recognizer:main',
    'learner': 'face_tracking_ros.nodes.learner:main',
    'bag_player': 'face_tracking_ros.nodes.bag_player:main',
    'bag_recorder': 'face_tracking_ros.nodes.bag_recorder:main',
}

# Command-line tools that are not nodes.
TOOLS: dict[str, str] = {
    'face-tracking': 'face_tracking_ros.cli.main:main',
}

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={PACKAGE: ['py.typed', 'data/*.npz', 'data/*.png', 'data/*.json']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.xml')),
    ],
    install_requires=['setuptools'],
    # Automatic initialisation (auto_init): dlib's face detector and 68-point landmark model.
    extras_require={'detector': ['dlib-bin', 'face_recognition_models']},
    zip_safe=True,
    maintainer='face_tracking_ros maintainers',
    maintainer_email='face-tracking@example.com',
    description='3-D face tracking with a learned deformable face model, as ROS 2 nodes.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [f'{name} = {target}' for name, target in {**TOOLS, **NODES}.items()],
    },
)
