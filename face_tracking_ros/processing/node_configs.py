"""The mono_tracker's and stereo_tracker's inputs and node parameters, without their trackers.

What ``face-tracking track`` and the bag pipelines (:mod:`~face_tracking_ros.pipelines.bag_inputs`)
read to wire and configure a tracker: importing :mod:`.mono` or :mod:`.stereo` for them loaded
both trackers and their numba kernels whichever tracker ran.
"""

from __future__ import annotations

from dataclasses import dataclass

from face_tracking_ros.errors import check_fields
from face_tracking_ros.io import conversions
from face_tracking_ros.processing.base import Port, QosClass
from face_tracking_ros.processing.model_agreement import MODEL_PORT

MODEL = MODEL_PORT.topic

IMAGE = 'image'
COMPRESSED_IMAGE = 'image/compressed'
CAMERA_INFO = 'camera_info'


@dataclass(frozen=True)
class MonoNodeConfig:
    """Parameters of the mono_tracker node besides the tracker's own.

    Attributes:
        model_file: face model file (.npz); empty: the packaged default model. A model received
            on face/model replaces it.
        init_file: YAML or JSON file of node names to pixel positions in the first image
            (semi-automatic initialisation); empty: wait for the reset_tracking service, or
            detect the face with auto_init.
        auto_init: automatic initialisation: find the face and its landmarks with dlib's
            68-point predictor (an optional extra: pip install dlib-bin
            face_recognition_models; parameters detector.*) in the first image, when there is
            no init_file, after every reset_tracking call without node positions, and to find
            the face again after a loss; a face found that the lost track's keyframes do not
            match (another person) starts a new track from the second LOST image on.
        face_id: face_id of the outputs; not empty or blank.
        compressed: subscribe to image/compressed (sensor_msgs/CompressedImage) instead of image.
        rectify: the images are raw (image_raw): rectify them with camera_info's K, D, R and P
            before tracking, as image_proc does (nothing to do for a camera without distortion
            or rectification), and read the pixel positions of init_file and reset_tracking in
            the raw image; false for images that arrive rectified with the raw camera's
            camera_info (image_rect).
    """

    model_file: str = ''
    init_file: str = ''
    auto_init: bool = False
    face_id: str = 'face_0'
    compressed: bool = False
    rectify: bool = True

    def __post_init__(self) -> None:
        """Validate the face_id.

        Raises:
            ConfigError: if it is empty or blank.
        """
        check_fields(self, {'face_id': bool(self.face_id.strip())})


LEFT_IMAGE, RIGHT_IMAGE = 'left/image_raw', 'right/image_raw'
COMPRESSED = {f'{LEFT_IMAGE}/compressed': LEFT_IMAGE, f'{RIGHT_IMAGE}/compressed': RIGHT_IMAGE}
LEFT_INFO, RIGHT_INFO = 'left/camera_info', 'right/camera_info'
INFOS = (LEFT_INFO, RIGHT_INFO)


@dataclass(frozen=True)
class StereoNodeConfig:
    """Parameters of the stereo_tracker node besides the tracker's own.

    Attributes:
        model_file: face model file (.npz) to fit pose, sigma and alpha to the tracked nodes;
            empty: meshes only, unless a model arrives on face/model.
        init_file: YAML or JSON file of node names to left-image pixel positions in the first
            pair (semi-automatic initialisation); empty: wait for the reset_tracking service,
            or detect the face with auto_init.
        auto_init: automatic initialisation: find the face and its landmarks in the left image
            with dlib's 68-point predictor (an optional extra: pip install dlib-bin
            face_recognition_models; parameters detector.*), when there is no init_file, after
            every reset_tracking call without node positions and after a loss; the landmarks are
            matched in the right image and the rest of the mesh placed from the reference face,
            as for an init file.
        rectify: the images are raw (image_raw): rectify each with its camera_info's K, D, R
            and P before tracking, as stereo_image_proc does (nothing to do for cameras without
            distortion or rectification), and read the pixel positions of init_file and
            reset_tracking in the raw left image; false for images that arrive rectified with
            the raw cameras' camera_info (image_rect).
        compressed: subscribe to left/image_raw/compressed and right/image_raw/compressed
            (sensor_msgs/CompressedImage, JPEG or PNG, as image_transport's compressed plugin
            publishes them) instead of the Image topics.
        face_id: face_id of the outputs; not empty or blank.
        pairing_queue: unpaired images kept per camera while waiting for the other camera's
            image with the same stamp (>= 1).
        pairing_tolerance_ms: pair a left and a right image whose stamps differ by at most this
            much, the nearest one waiting; 0 (the default): equal stamps only, as synchronised
            stereo cameras (one driver, one trigger) stamp them. For two free-running cameras,
            about a third of the frame period; their images are then up to that far apart in
            time, which a moving face turns into depth error.
        retroactive_depths: offline replay only (face-tracking track, learn; the live node
            refuses it): refine the frame-1 node depths over every pair (turns
            tracker.refine_depths on), hold each track's outputs until it ends (a reset or the
            end of the bag; about 20 kB per pair) and emit them with the final depths applied to
            every pair. The default of face-tracking learn on raw stereo bags: on the 380-frame
            still sequences of subjects 0 and 1, node RMS 5.5 / 2.1 -> 1.5 / 1.8 mm from exact
            clicks, 5.8 / 3.0 -> 3.4 / 3.4 mm from clicks with 1 px of noise.
    """

    model_file: str = ''
    init_file: str = ''
    auto_init: bool = False
    rectify: bool = True
    compressed: bool = False
    face_id: str = 'face_0'
    pairing_queue: int = 10
    pairing_tolerance_ms: float = 0.0
    retroactive_depths: bool = False

    def __post_init__(self) -> None:
        """Validate the face_id and the pairing.

        Raises:
            ConfigError: naming the first invalid field.
        """
        checks = {
            'face_id': bool(self.face_id.strip()),
            'pairing_queue': self.pairing_queue >= 1,
            'pairing_tolerance_ms': 0.0 <= self.pairing_tolerance_ms < 1000.0,
        }
        check_fields(self, checks)


def stereo_input_ports(compressed: bool) -> tuple[Port, ...]:
    """The stereo_tracker's inputs: both images (raw or ``compressed``), camera_infos and model."""
    image_type, image_topics = (
        (conversions.COMPRESSED_IMAGE_TYPE, tuple(COMPRESSED))
        if compressed
        else (conversions.IMAGE_TYPE, (LEFT_IMAGE, RIGHT_IMAGE))
    )
    return (
        *(Port(topic, image_type, QosClass.SENSOR) for topic in image_topics),
        Port(LEFT_INFO, conversions.CAMERA_INFO_TYPE, QosClass.SENSOR),
        Port(RIGHT_INFO, conversions.CAMERA_INFO_TYPE, QosClass.SENSOR),
        MODEL_PORT,
    )
