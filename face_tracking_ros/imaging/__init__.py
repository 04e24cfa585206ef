"""Image helpers shared by the monocular and stereo trackers.

Grey conversion (:mod:`.gray`), float32 Gaussian pyramids (:mod:`.pyramid`), sub-pixel sampling
of patches with their image gradients through one ``cv2.remap`` call (:mod:`.sampling`) and
patch residuals invariant to brightness changes (:mod:`.photometric`, imported from there: loaded
with this package, its compiled kernels and numba took 0.28 s of every command that converts an
image message, a stereo track's and a recogniser's replay too).
"""

from face_tracking_ros.imaging.gray import SUPPORTED_ENCODINGS, to_gray
from face_tracking_ros.imaging.photometric_model import PhotometricModel
from face_tracking_ros.imaging.pyramid import (
    ImagePyramid,
    PyramidLevel,
    check_levels_fit,
    tracking_levels,
)
from face_tracking_ros.imaging.sampling import (
    GRADIENT_MARGIN,
    MAX_HALF_SIZE,
    STENCIL_X,
    STENCIL_Y,
    inside_image,
    inside_xy,
    sample_maps,
    sample_patches,
    sample_points,
    sample_stencils,
    sample_with_gradient_xy,
    sample_xy,
    square_offsets,
)

__all__ = [
    'GRADIENT_MARGIN',
    'STENCIL_X',
    'STENCIL_Y',
    'SUPPORTED_ENCODINGS',
    'ImagePyramid',
    'PhotometricModel',
    'PyramidLevel',
    'check_levels_fit',
    'inside_image',
    'inside_xy',
    'sample_patches',
    'sample_maps',
    'sample_points',
    'sample_stencils',
    'sample_with_gradient_xy',
    'sample_xy',
    'square_offsets',
    'tracking_levels',
    'MAX_HALF_SIZE',
    'to_gray',
]
