"""Helpers of the hardening tests: a small rendered face scene with truth, and input messages.

The scene is one synthetic subject in front of a cluttered backdrop, seen by a 320x240 camera;
any pose, occluder or light can be rendered, so a test builds exactly the fault it needs (a face
leaving the image, a hand in front of it, the light switched) with the true nodes alongside.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.recognition.expression import ExpressionClassifier
from face_tracking_ros.synthetic.background import Backdrop
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.render import FacePose, FaceRenderer, Lighting, Occluder
from face_tracking_ros.synthetic.texture import procedural_texture
from face_tracking_ros.synthetic.true_model import true_face_model
from face_tracking_ros.tracking.initialisation import Initialisation

CAMERA = PinholeCamera.ideal(320, 240, 300.0)
DEPTH = 0.6  # m, face distance
FPS = 15.0
FRAME_NS = round(1e9 / FPS)
T0_NS = 1_700_000_000_000_000_000
FACTORY = RosbagsMessages(typestore())


@dataclass(frozen=True)
class Frame:
    """A rendered image and the true (34, 3) camera-frame nodes, m."""

    image: np.ndarray
    nodes: np.ndarray


class FaultScene:
    """One subject rendered at chosen poses, with occluders and light of the test's choosing."""

    def __init__(self, subject: int = 3, seed: int = 0) -> None:
        """Build the subject's texture, the backdrop and the true model (a few seconds)."""
        self.population = FacePopulation(seed=seed)
        self._subject = self.population.subject(subject)
        self._renderer = FaceRenderer(procedural_texture(self._subject.appearance_seed))
        self._backdrop = Backdrop.cluttered(CAMERA.width, CAMERA.height, seed + 5)
        self._nodes = self.population.nodes(self._subject, {})
        self.model = true_face_model(self.population)

    def render(
        self,
        yaw: float = 0.0,
        x: float = 0.0,
        occluders: Sequence[Occluder] = (),
        lighting: Lighting | None = None,
        noise_seed: int = 0,
        camera: PinholeCamera = CAMERA,
    ) -> Frame:
        """The face at yaw (rad) and lateral offset x (m) at :data:`DEPTH`, with sensor noise.

        The true nodes are in the reference camera frame (for a rig: the left camera's).
        """
        pose = FacePose(self._nodes, np.array([0.0, yaw, 0.0]), np.array([x, 0.0, DEPTH]))
        image = self._renderer.render(
            camera,
            [pose],
            self._backdrop.view(camera, 'mono8'),
            lighting,
            occluders,
            rng=np.random.default_rng(noise_seed),
        )
        return Frame(image, pose.camera_nodes())

    def initialisation(self, frame: Frame) -> Initialisation:
        """Exact 2-D node positions of a frame (a perfect click-initialisation)."""
        return Initialisation(self.model.node_names, CAMERA.project(frame.nodes))


def image_msg(pixels: np.ndarray, stamp_ns: int, encoding: str = '') -> object:
    """A rosbags sensor_msgs/Image of an array, stamped ``stamp_ns``."""
    header = conversions.make_header(FACTORY, stamp_ns, 'camera_optical')
    return conversions.array_to_image(FACTORY, header, pixels, encoding)


def info_msg(camera: PinholeCamera = CAMERA, stamp_ns: int = T0_NS) -> object:
    """A rosbags sensor_msgs/CameraInfo of a camera."""
    header = conversions.make_header(FACTORY, stamp_ns, 'camera_optical')
    return conversions.camera_to_info(FACTORY, header, camera)


def stamp(frame: int) -> int:
    """Stamp of frame ``frame`` at :data:`FPS`, ns."""
    return T0_NS + frame * FRAME_NS


def smile_classifier() -> ExpressionClassifier:
    """A q = 1 classifier: 'smile' when alpha > 0.5 (posterior sigmoid(20 alpha - 10)))."""
    return ExpressionClassifier(
        labels=('neutral', 'smile'),
        q=1,
        window=0.2,
        calibration=0.0,
        feature_mean=np.zeros(3),
        feature_scale=np.ones(3),
        weights=np.array([[0.0, 0.0, 0.0], [20.0, 0.0, 0.0]]),
        intercepts=np.array([0.0, -10.0]),
    )
