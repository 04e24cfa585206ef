"""Image helpers shared by the monocular and stereo trackers.

Grey conversion (:mod:`.gray`), float32 Gaussian pyramids (:mod:`.pyramid`), sub-pixel sampling
of patches with their image gradients through one ``cv2.remap`` call (:mod:`.sampling`) and
patch residuals invariant to brightness changes (:mod:`.photometric`).
"""

from face_tracking_ros.imaging.gray import SUPPORTED_ENCODINGS, to_gray
from face_tracking_ros.imaging.photometric import (
    PhotometricInvariance,
    PhotometricModel,
    PhotometricProjection,
)
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
    'PhotometricInvariance',
    'PhotometricModel',
    'PhotometricProjection',
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
