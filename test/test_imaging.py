"""Tests of face_tracking_ros.imaging: grey conversion, pyramids, sub-pixel sampling."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.imaging import (
    STENCIL_X,
    STENCIL_Y,
    ImagePyramid,
    PhotometricModel,
    check_levels_fit,
    inside_image,
    inside_xy,
    sample_patches,
    sample_points,
    sample_stencils,
    sample_with_gradient_xy,
    sample_xy,
    square_offsets,
    to_gray,
)
from face_tracking_ros.imaging.photometric import PhotometricProjection


def _ramp(height: int = 60, width: int = 80) -> np.ndarray:
    """A linear image I(x, y) = 0.7 x + 1.3 y + 5, float32."""
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    return (0.7 * cols + 1.3 * rows + 5.0).astype(np.float32)


def test_to_gray_mono8_is_a_view_and_colour_orders_agree() -> None:
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    mono = rgb[:, :, 0].copy()
    assert to_gray(mono, 'mono8').base is mono or to_gray(mono, 'mono8') is mono
    assert np.array_equal(to_gray(mono[:, :, None], 'mono8'), mono)
    from_rgb = to_gray(rgb, 'rgb8')
    assert from_rgb.shape == (12, 16) and from_rgb.dtype == np.uint8
    assert np.array_equal(from_rgb, to_gray(rgb[:, :, ::-1].copy(), 'bgr8'))
    # ITU-R 601 luma of pure red is 0.299 * 255.
    red = np.zeros((2, 2, 3), np.uint8)
    red[..., 0] = 255
    assert abs(int(to_gray(red, 'rgb8')[0, 0]) - 76) <= 1


def _mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """The Bayer mosaic of an RGB image: ``pattern`` names the colours of a 2x2 cell row-wise."""
    channel = {'r': 0, 'g': 1, 'b': 2}
    mosaic = np.zeros(rgb.shape[:2], np.uint8)
    for k, colour in enumerate(pattern):
        rows, columns = divmod(k, 2)
        mosaic[rows::2, columns::2] = rgb[rows::2, columns::2, channel[colour]]
    return mosaic


@pytest.mark.parametrize('pattern', ['rggb', 'bggr', 'gbrg', 'grbg'])
def test_bayer_images_demosaic_to_the_grey_of_their_colours(pattern: str) -> None:
    rgb = np.empty((16, 20, 3), np.uint8)
    rgb[...] = (200, 100, 30)  # a flat colour, so demosaicing recovers it exactly inside
    gray = to_gray(_mosaic(rgb, pattern), f'bayer_{pattern}8')
    expected = to_gray(rgb, 'rgb8')
    assert gray.shape == (16, 20)
    np.testing.assert_array_equal(gray[2:-2, 2:-2], expected[2:-2, 2:-2])  # 122; others 90-159


def test_yuv422_images_give_their_luma() -> None:
    rng = np.random.default_rng(1)
    luma = rng.integers(16, 236, (6, 8), dtype=np.uint8)
    chroma = rng.integers(16, 241, (6, 8), dtype=np.uint8)
    uyvy = np.stack([chroma, luma], axis=2)  # U Y V Y ...: chroma first in each pixel pair
    yuyv = np.stack([luma, chroma], axis=2)
    np.testing.assert_array_equal(to_gray(uyvy, 'yuv422'), luma)
    np.testing.assert_array_equal(to_gray(yuyv, 'yuv422_yuy2'), luma)


@pytest.mark.parametrize(
    ('array', 'encoding', 'match'),
    [
        (np.zeros((4, 4), np.uint16), 'mono16', 'unsupported image encoding'),
        (np.zeros((4, 4), np.uint8), 'yuv422', r'must be \(H, W, 2\)'),
        (np.zeros((4, 4), np.uint16), 'mono8', 'must be uint8'),
        (np.zeros((4, 4, 3), np.uint8), 'mono8', r'must be \(H, W\)'),
        (np.zeros((4, 4), np.uint8), 'rgb8', r'must be \(H, W, 3\)'),
        (np.zeros((0, 4, 3), np.uint8), 'bgr8', r'must be \(H, W, 3\)'),
    ],
)
def test_to_gray_rejects_bad_input(array: np.ndarray, encoding: str, match: str) -> None:
    with pytest.raises(InputError, match=match):
        to_gray(array, encoding)


def test_pyramid_levels_and_coordinates() -> None:
    image = np.zeros((96, 128), np.uint8)
    image[40:44, 70:74] = 255  # blob centred at (71.5, 41.5)
    pyramid = ImagePyramid.build(image, 3)
    assert pyramid.num_levels == 3 and pyramid.shape == (96, 128)
    assert [lvl.shape for lvl in pyramid.levels] == [(96, 128), (48, 64), (24, 32)]
    assert all(lvl.dtype == np.float32 for lvl in pyramid.levels)
    for level in range(3):
        img = pyramid.levels[level]
        rows, cols = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
        centroid = np.array([(img * cols).sum(), (img * rows).sum()]) / img.sum()
        expected = ImagePyramid.to_level(np.array([71.5, 41.5]), level)
        assert np.allclose(centroid, expected, atol=0.02), (level, centroid, expected)


@pytest.mark.parametrize('smooth_base', [False, True])
def test_pyramid_rebuilt_into_a_previous_one_equals_a_new_one(smooth_base: bool) -> None:
    rng = np.random.default_rng(3)
    first, second = rng.integers(0, 256, size=(2, 61, 83), dtype=np.uint8)
    previous = ImagePyramid.build(first, 3, smooth_base)
    arrays = [id(level) for level in previous.levels]
    rebuilt = ImagePyramid.build(second, 3, smooth_base, reuse=previous)
    fresh = ImagePyramid.build(second, 3, smooth_base)
    assert [id(level) for level in rebuilt.levels] == arrays
    for got, expected in zip(rebuilt.levels, fresh.levels, strict=True):
        np.testing.assert_array_equal(got, expected)
    # A pyramid of another size or kind is not reused.
    other = ImagePyramid.build(second, 2, not smooth_base, reuse=rebuilt)
    assert not {id(level) for level in other.levels} & set(arrays)


@pytest.mark.parametrize('smooth_base', [False, True])
def test_pyramid_deepened_equals_the_deeper_build(smooth_base: bool) -> None:
    """Its levels stay its own arrays; the added ones are those a deeper build makes."""
    image = np.random.default_rng(4).integers(0, 256, size=(61, 83), dtype=np.uint8)
    pyramid = ImagePyramid.build(image, 2, smooth_base)
    arrays = [id(level) for level in pyramid.levels]
    pyramid.deepen(3)
    assert pyramid.num_levels == 3
    assert [id(level) for level in pyramid.levels[:2]] == arrays
    for got, expected in zip(
        pyramid.levels, ImagePyramid.build(image, 3, smooth_base).levels, strict=True
    ):
        np.testing.assert_array_equal(got, expected)
    with pytest.raises(InputError, match='cannot build 4 pyramid levels'):
        pyramid.deepen(4)  # level 3 would keep 7 px


def test_pyramid_deepened_again_makes_no_level_twice_and_scales_with_it() -> None:
    """The added levels are made once and kept: deepened again, to as many or more levels.

    A stereo pair's deepened pyramids are the last pair's on the next pair, and frame 1's on
    every pair a fast head or a gap solves from an added level; :meth:`scale` multiplies the
    kept levels too, so a later deepening carries the factor as a deeper build scaled does.
    """
    image = np.random.default_rng(6).integers(0, 256, size=(64, 96), dtype=np.uint8)
    pyramid = ImagePyramid.build(image, 2)
    pyramid.deepen(3)
    third = pyramid.levels[2]
    pyramid.deepen(4)
    assert pyramid.levels[2] is third
    pyramid.deepen(3)
    assert pyramid.levels[2] is third and pyramid.num_levels == 4
    pyramid.scale(0.5)
    expected = ImagePyramid.build(image, 4)
    expected.scale(0.5)
    for got, want in zip(pyramid.levels, expected.levels, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-4)


def test_pyramid_deepened_of_a_borrowed_image_owned_carries_the_factor() -> None:
    """A borrowed, partly made pyramid owning its image deepens as a deeper build scaled.

    The stereo tracker keeps the last pair's pyramids past the pair (the caller then reuses the
    images) and deepens them after a gap: the levels are those of the image as built, the added
    one carries the right camera's gain factor (within float32 rounding).
    """
    rng = np.random.default_rng(5)
    image, other = rng.integers(0, 256, size=(2, 61, 83), dtype=np.uint8)
    borrowed = other.copy()
    before = ImagePyramid.build(borrowed, 2, factor=0.8, borrow=True)
    before.own()  # its copy of the image is the buffer the next pyramid owns its image in
    borrowed[...] = image
    pyramid = ImagePyramid.build(borrowed, 2, reuse=before, factor=0.8, borrow=True)
    pyramid.level(1, np.array([10.0]), np.array([12.0]))  # a box of levels 0 and 1 made
    pyramid.own()
    borrowed[...] = other  # the caller's next image
    expected = ImagePyramid.build(image, 3)
    expected.scale(0.8)
    pyramid.deepen(3)
    for got, want in zip(pyramid.levels[:2], expected.levels[:2], strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(pyramid.levels[2], expected.levels[2], rtol=1e-6, atol=1e-4)
    assert np.abs(pyramid.levels[2] - ImagePyramid.build(image, 3).levels[2]).max() > 1.0


@pytest.mark.parametrize('dtype', [np.uint8, np.float32])
@pytest.mark.parametrize('smooth_base', [False, True])
def test_pyramid_read_where_sampled_equals_the_full_build(smooth_base: bool, dtype: type) -> None:
    """Samples through ``level`` (level 0 made over boxes only) equal the full build's.

    The buffers are reused from another image's pyramid, so a pixel read outside the box made
    holds that image's value, and clusters of points all over (some beyond the image's edges,
    where the border pixels are read) grow the box one after the other.
    """
    rng = np.random.default_rng(7)
    height, width = 97, 131
    other, image = (rng.random((2, height, width)) * 255).astype(dtype)
    previous = ImagePyramid.build(other, 3, smooth_base)
    previous.levels  # noqa: B018 - made in full, as a tracker's previous frame may be
    pyramid = ImagePyramid.build(image, 3, smooth_base, reuse=previous)
    full = ImagePyramid.build(image, 3, smooth_base).levels
    # 8-bit images: the same to the bit; float ones within float32 rounding.
    same = np.testing.assert_array_equal if dtype == np.uint8 else np.testing.assert_allclose
    for cluster in range(40):
        centre = rng.uniform([-10, -10], [width + 10, height + 10])
        x, y = (centre[:, None, None] + rng.normal(0.0, 3.0, (2, 5, 9))).astype(np.float32)
        values, gradient = sample_with_gradient_xy(pyramid.level(0, x, y), x, y)
        expected_values, expected_gradient = sample_with_gradient_xy(full[0], x, y)
        same(values, expected_values)
        same(gradient, expected_gradient)
        if cluster == 20:  # a coarse level is made in full, level 0 with it
            x1, y1 = x / 2, y / 2
            same(sample_xy(pyramid.level(1, x1, y1), x1, y1), sample_xy(full[1], x1, y1))
    for got, expected in zip(pyramid.levels, full, strict=True):
        same(got, expected)


def test_pyramid_made_where_sampled_only() -> None:
    """A read of a few points makes level 0 around them, not the whole image (its purpose)."""
    image = np.full((200, 300), 100, np.uint8)
    previous = ImagePyramid.build(np.zeros_like(image), 2, smooth_base=True)
    previous.levels  # noqa: B018
    pyramid = ImagePyramid.build(image, 2, smooth_base=True, reuse=previous)
    x, y = np.float32([[150.5, 152.5]]), np.float32([[100.5, 101.5]])
    level = pyramid.level(0, x, y)
    made = level == 100
    rows, cols = np.nonzero(made)
    assert made[100, 150] and made.sum() < 0.05 * made.size
    # Made: the pixels the samples read (floor - 1 to floor + 2 of x and y, central
    # differences), 2 more either side for rounding to 1/32 px (_SAMPLE_REACH = 3, exclusive
    # end + 1), the margin of 4 and the 2 px the 5-tap kernel writes around its box.
    assert (rows.min(), rows.max()) == (100 - 3 - 4 - 2, 101 + 3 + 4 + 2)
    assert (cols.min(), cols.max()) == (150 - 3 - 4 - 2, 152 + 3 + 4 + 2)
    with pytest.raises(InputError, match='NaN'):
        pyramid.level(0, np.float32([np.nan]), np.float32([1.0]))


@pytest.mark.parametrize('smooth_base', [False, True])
@pytest.mark.parametrize('borrow', [False, True])
@pytest.mark.parametrize('factor', [1.0, 1 / 1.0077])
def test_8_bit_levels_read_by_boxes_equal_the_scaled_full_build(
    factor: float, borrow: bool, smooth_base: bool
) -> None:
    """Levels 0 and 1 of an 8-bit image, made by boxes, are the full build's bits.

    As the trackers read them (the stereo tracker's scaled by the right camera's gain at build,
    its image borrowed), the buffers of another image's pyramid reused; clusters of points all
    over (some beyond the edges, odd sizes) grow the boxes.
    """
    rng = np.random.default_rng(11)
    height, width = 97, 131
    other, image = rng.integers(0, 256, (2, height, width), dtype=np.uint8)
    previous = ImagePyramid.build(other, 3, smooth_base, borrow=borrow)
    previous.levels  # noqa: B018 - made in full, so a pixel read outside a box holds other's
    kept = image.copy()
    image.flags.writeable = False  # as a message's buffer may be
    pyramid = ImagePyramid.build(image, 3, smooth_base, previous, factor, borrow)
    full = ImagePyramid.build(image, 3, smooth_base)
    full.scale(factor)
    for cluster in range(40):
        level = cluster % 2
        size = np.array([width, height]) / (1 << level)
        centre = rng.uniform(-5, size + 5)
        x, y = (centre[:, None, None] + rng.normal(0.0, 3.0, (2, 5, 9))).astype(np.float32)
        values, gradient = sample_with_gradient_xy(pyramid.level(level, x, y), x, y)
        expected_values, expected_gradient = sample_with_gradient_xy(full.levels[level], x, y)
        np.testing.assert_array_equal(values, expected_values)
        np.testing.assert_array_equal(gradient, expected_gradient)
    np.testing.assert_array_equal(image, kept)  # a borrowed image is read, never written
    for got, expected in zip(pyramid.levels, full.levels, strict=True):
        np.testing.assert_array_equal(got, expected)
    image.flags.writeable = True
    image[...] = 0  # the caller's buffer, free once the pyramid is made in full
    np.testing.assert_array_equal(pyramid.levels[0], full.levels[0])


def test_unsmoothed_level_1_made_where_sampled_only() -> None:
    """A read of a few points of level 1 makes it around them, to the bit, level 0 not at all.

    (Smoothed, level 1 is made from level 0, made over the box first.)
    """
    image = np.random.default_rng(5).integers(1, 256, (200, 300), dtype=np.uint8)
    previous = ImagePyramid.build(np.zeros_like(image), 2)
    previous.levels  # noqa: B018
    pyramid = ImagePyramid.build(image, 2, reuse=previous, borrow=True)
    x, y = np.float32([[70.5, 71.5]]), np.float32([[50.5, 51.5]])
    level = pyramid.level(1, x, y)
    made = level > 0
    np.testing.assert_array_equal(level[made], ImagePyramid.build(image, 2).levels[1][made])
    rows, cols = np.nonzero(made)
    # The pixels the samples read (_SAMPLE_REACH = 3, exclusive end + 1) and the margin of 4.
    assert (rows.min(), rows.max()) == (50 - 3 - 4, 51 + 3 + 4)
    assert (cols.min(), cols.max()) == (70 - 3 - 4, 71 + 3 + 4)
    assert not pyramid.level(0, np.float32([]), np.float32([])).any()


@pytest.mark.parametrize('factor', [1.0, 1 / 1.0077])
def test_added_levels_read_by_boxes_are_the_bits_of_the_whole_levels_reduced(
    factor: float,
) -> None:
    """Levels added by ``deepen``, made where sampled, are ``pyrDown`` of the level above's bits.

    As the stereo tracker reads them on a fast or gap pair: its right pyramids scaled by the
    camera's gain (float levels, which ``pyrDown`` rounds differently in its vector and scalar
    paths), its images borrowed, 1280x720 and odd sizes; clusters of points all over (some
    beyond the edges) grow the boxes of levels 2 and 3 and, below them, of levels 1 and 0.
    """
    rng = np.random.default_rng(12)
    for height, width in ((720, 1280), (197, 331)):
        image = rng.integers(0, 256, (height, width), dtype=np.uint8)
        pyramid = ImagePyramid.build(image, 2, factor=factor, borrow=True)
        pyramid.deepen(4)
        full = ImagePyramid.build(image, 2)
        full.scale(factor)
        expected = [*full.levels]
        for _ in range(2):
            expected.append(cv2.pyrDown(expected[-1]))
        for cluster in range(40):
            level = 2 + cluster % 2
            size = np.array([width, height]) / (1 << level)
            centre = rng.uniform(-5, size + 5)
            x, y = (centre[:, None, None] + rng.normal(0.0, 3.0, (2, 5, 9))).astype(np.float32)
            values, gradient = sample_with_gradient_xy(pyramid.level(level, x, y), x, y)
            want_values, want_gradient = sample_with_gradient_xy(expected[level], x, y)
            np.testing.assert_array_equal(values, want_values)
            np.testing.assert_array_equal(gradient, want_gradient)
        for got, want in zip(pyramid.levels, expected, strict=True):
            np.testing.assert_array_equal(got, want)


def test_an_added_level_made_where_sampled_only() -> None:
    """A read of a few points of an added level makes it and level 1 around them, level 0 not.

    The stereo tracker's fast-motion level at 1280x720 read a face's patches and made both
    images' levels 0 and 1 in full for it (1.6 ms a pair).
    """
    image = np.random.default_rng(8).integers(1, 256, (720, 1280), dtype=np.uint8)
    previous = ImagePyramid.build(np.zeros_like(image), 2)
    previous.levels  # noqa: B018 - made in full, so a pixel not made holds 0
    pyramid = ImagePyramid.build(image, 2, reuse=previous, borrow=True)
    pyramid.deepen(3)
    x, y = np.float32([[150.5, 160.5]]), np.float32([[80.5, 90.5]])
    level = pyramid.level(2, x, y)
    full = ImagePyramid.build(image, 3).levels
    # The pixels the samples read (_SAMPLE_REACH = 3, exclusive end + 1) and the margin of 4.
    reach = np.s_[80 - 3 - 4 : 90 + 3 + 4 + 1, 150 - 3 - 4 : 160 + 3 + 4 + 1]
    np.testing.assert_array_equal(level[reach], full[2][reach])
    made = pyramid.level(1, x[:, :0], y[:, :0]) > 0  # nothing read: level 1 as made so far
    assert 0 < made.sum() < 0.02 * made.size
    np.testing.assert_array_equal(pyramid.level(1, x[:, :0], y[:, :0])[made], full[1][made])
    assert not pyramid.level(0, x[:, :0], y[:, :0]).any()  # level 1 is reduced from the image


def test_a_single_smoothed_level_is_the_binomial_smoothing_of_the_image() -> None:
    image = np.zeros((32, 32), np.uint8)
    image[10, 12] = 255  # an impulse: smoothed, the 5-tap binomial kernel's outer product
    binomial = np.array([1, 4, 6, 4, 1]) / 16
    expected = np.zeros((32, 32), np.float32)
    expected[8:13, 10:15] = 255 * np.outer(binomial, binomial)
    np.testing.assert_array_equal(
        ImagePyramid.build(image, 1, smooth_base=True).levels[0], expected
    )
    pyramid = ImagePyramid.build(image, 1, smooth_base=True)
    x, y = np.float32([[12.0]]), np.float32([[10.0]])
    np.testing.assert_array_equal(pyramid.level(0, x, y)[8:13, 10:15], expected[8:13, 10:15])


def test_a_scaled_pyramid_is_the_pyramid_of_the_scaled_image() -> None:
    image = np.random.default_rng(9).integers(0, 256, (48, 64), dtype=np.uint8)
    pyramid = ImagePyramid.build(image, 3, smooth_base=True)
    pyramid.scale(0.5)
    halved = ImagePyramid.build(image.astype(np.float32) / 2, 3, smooth_base=True).levels
    for got, expected in zip(pyramid.levels, halved, strict=True):
        np.testing.assert_array_equal(got, expected)  # halving is exact in float32


def test_check_levels_fit_allows_the_levels_whose_coarsest_keeps_16_px() -> None:
    check_levels_fit(5, 640, 480)  # level 4: 480 / 16 = 30 px on the shorter side
    with pytest.raises(
        ConfigError, match=r'pyramid_levels = 6 is too deep for 640x480 .* at most 5 '
    ):
        check_levels_fit(6, 640, 480)  # level 5 would keep 15 px
    check_levels_fit(1, 16, 16)
    with pytest.raises(ConfigError, match='at most 1 leave'):
        check_levels_fit(2, 31, 100)


@pytest.mark.parametrize(
    ('image', 'levels', 'match'),
    [
        (np.zeros((10, 10, 3)), 1, 'grey image'),
        (np.zeros((24, 40)), 3, 'cannot build 3 pyramid levels'),
        (np.zeros((32, 32)), 0, 'cannot build 0'),
        (np.full((16, 16), np.nan), 1, 'NaN'),
    ],
)
def test_pyramid_rejects_bad_input(image: np.ndarray, levels: int, match: str) -> None:
    with pytest.raises(InputError, match=match):
        ImagePyramid.build(image, levels)


def test_sample_points_is_exact_on_a_ramp_and_keeps_shape() -> None:
    image = _ramp()
    rng = np.random.default_rng(1)
    points = rng.uniform([0, 0], [79, 59], size=(3, 5000, 2))  # > 4096: folded map
    values = sample_points(image, points)
    assert values.shape == (3, 5000) and values.dtype == np.float32
    expected = 0.7 * points[..., 0] + 1.3 * points[..., 1] + 5.0
    assert np.abs(values - expected).max() < 1e-3
    assert sample_points(image, np.zeros((0, 2))).shape == (0,)


def test_sample_points_replicates_the_border() -> None:
    image = _ramp()
    assert sample_points(image, np.array([[-5.0, 0.0]]))[0] == pytest.approx(5.0)
    assert sample_points(image, np.array([[79.0, 70.0]]))[0] == pytest.approx(
        0.7 * 79 + 1.3 * 59 + 5
    )


@pytest.mark.parametrize(
    ('image', 'points', 'match'),
    [
        (np.zeros((8, 8)), np.zeros((1, 2)), 'float32'),
        (np.zeros((8, 8, 2), np.float32), np.zeros((1, 2)), r'\(H, W\) float32'),
        (np.zeros((8, 8), np.float32), np.zeros((1, 3)), r'\(\.\.\., 2\)'),
        (np.zeros((8, 8), np.float32), np.array([[np.nan, 1.0]]), 'NaN'),
    ],
)
def test_sample_points_rejects_bad_input(
    image: np.ndarray, points: np.ndarray, match: str
) -> None:
    with pytest.raises(InputError, match=match):
        sample_points(image, points)


def test_sample_patches_matches_pointwise_sampling() -> None:
    rng = np.random.default_rng(2)
    image = rng.uniform(0, 255, (50, 60)).astype(np.float32)
    offsets = square_offsets(2, 0.5)
    assert offsets.shape == (25, 2)
    assert np.array_equal(offsets[0], [-1.0, -1.0]) and np.array_equal(offsets[1], [-0.5, -1.0])
    centres = rng.uniform(5, 40, (7, 2))
    patches = sample_patches(image, centres, offsets)
    assert patches.shape == (7, 25)
    direct = sample_points(image, (centres[:, None, :] + offsets[None]).reshape(-1, 2))
    assert np.allclose(patches.ravel(), direct, atol=1e-4)


def test_square_offsets_rejects_bad_size() -> None:
    with pytest.raises(InputError, match='half size'):
        square_offsets(-1)
    with pytest.raises(InputError, match='step > 0'):
        square_offsets(2, 0.0)


def test_sample_with_gradient_on_ramp_and_smooth_image() -> None:
    x, y = np.random.default_rng(3).uniform(3, 50, (2, 40))
    values, gradient = sample_with_gradient_xy(_ramp(), x, y)
    assert np.allclose(gradient.T, [0.7, 1.3], atol=1e-3)
    assert np.allclose(values, 0.7 * x + 1.3 * y + 5, atol=1e-3)
    # A smooth sinusoid: central differences match the analytic derivative to O(h^2).
    rows, cols = np.mgrid[0:64, 0:64].astype(np.float64)
    wave = 100 * np.sin(cols / 9.0) * np.cos(rows / 7.0)
    _, grad = sample_with_gradient_xy(wave.astype(np.float32), x, y)
    expected = np.stack(
        [100 / 9 * np.cos(x / 9) * np.cos(y / 7), -100 / 7 * np.sin(x / 9) * np.sin(y / 7)]
    )
    assert np.abs(grad - expected).max() < 0.25  # of gradients up to 14 grey levels / px


@pytest.mark.parametrize('shape', [(0, 5), (5, 0), (0,)])
def test_no_points_sample_to_an_empty_array_of_their_shape(shape) -> None:
    # cv2.remap refuses empty maps: an empty (H, W) map must not reach it.
    x = y = np.zeros(shape, np.float32)
    for values in (sample_xy(_ramp(), x, y), sample_with_gradient_xy(_ramp(), x, y)[0]):
        assert values.shape == shape and values.dtype == np.float32


# (1, 32767): one map as wide as cv2.remap refuses (SHRT_MAX), so the points are reshaped.
@pytest.mark.parametrize('shape', [(6, 7), (3, 5000), (1, 32767), (2, 3, 4), (11,)])
def test_separate_coordinates_sample_exactly_like_interleaved_points(shape) -> None:
    rng = np.random.default_rng(6)
    image = rng.uniform(0, 255, (40, 50)).astype(np.float32)
    points = rng.uniform(-2, 52, (*shape, 2))
    x, y = points[..., 0], points[..., 1]
    np.testing.assert_array_equal(sample_xy(image, x, y), sample_points(image, points))
    values_xy, gradient_xy = sample_with_gradient_xy(image, x, y)
    np.testing.assert_array_equal(values_xy, sample_xy(image, x, y))
    assert gradient_xy.shape == (2, *shape)
    np.testing.assert_array_equal(
        inside_xy(x, y, image.shape, 1.5), inside_image(points, image.shape, 1.5)
    )
    with pytest.raises(InputError, match='differ in shape'):
        sample_xy(image, x, y[..., :1])
    with pytest.raises(InputError, match='NaN or Inf'):
        sample_xy(image, np.full(shape, np.nan), y)


def test_images_sampled_at_once_equal_each_sampled_alone() -> None:
    rng = np.random.default_rng(7)
    images = [rng.uniform(0, 255, (40, 50)).astype(np.float32) for _ in range(2)]
    x, y = rng.uniform(-2, 52, (2, 2, 300))
    maps_x = x.astype(np.float32)[:, None, :] + STENCIL_X[:, None]  # (2, 5, 300)
    maps_y = y.astype(np.float32)[:, None, :] + STENCIL_Y[:, None]
    values, gradient = sample_stencils(images, maps_x, maps_y)
    assert values.shape == (2, 300) and gradient.shape == (2, 2, 300)
    for row, image in enumerate(images):
        alone, alone_gradient = sample_with_gradient_xy(image, x[row], y[row])
        np.testing.assert_array_equal(values[row], alone)
        np.testing.assert_array_equal(gradient[row], alone_gradient)
    with pytest.raises(InputError, match='for 2 images'):
        sample_stencils(images, maps_x[:1], maps_y[:1])
    with pytest.raises(InputError, match='float32'):
        sample_stencils([images[0], images[1].astype(float)], maps_x, maps_y)


def test_inside_image() -> None:
    points = np.array([[0.0, 0.0], [9.0, 4.0], [9.5, 4.0], [2.0, 2.0], [-0.1, 3.0]])
    assert inside_image(points, (5, 10)).tolist() == [True, True, False, True, False]
    assert inside_image(points, (5, 10), margin=2.0).tolist() == [False, False, False, True, False]


@pytest.mark.parametrize('model', list(PhotometricModel))
def test_photometric_projection_removes_exactly_its_brightness_changes(model) -> None:
    rng = np.random.default_rng(4)
    coordinates = square_offsets(3)
    u, v = coordinates[:, 0], coordinates[:, 1]
    template = rng.uniform(20, 230, (5, len(coordinates)))
    projection = PhotometricProjection.of(template, model, coordinates)
    changes = {
        PhotometricModel.BIAS: 12.0 + 0 * template,
        PhotometricModel.GAIN_BIAS: 0.3 * template - 7.0,
        PhotometricModel.GAIN_FIELD: (0.2 + 0.01 * u - 0.02 * v) * template + 3 + 0.5 * v,
    }
    for removed, change in changes.items():
        remaining = np.abs(projection.apply(change)).max() / np.abs(change).max()
        assert (remaining < 1e-6) == (model >= removed), (model, removed, remaining)
    # Idempotent, and (J, N, M) Jacobian-like arrays are projected row by row.
    values = rng.normal(size=template.shape)
    once = projection.apply(values)
    assert np.allclose(projection.apply(once), once)
    stacked = projection.apply(np.stack([values, 2 * values]))
    assert np.allclose(stacked[1], 2 * once)


@pytest.mark.parametrize('model', list(PhotometricModel))
def test_photometric_projection_of_float32_samples_is_float64(model) -> None:
    """Every model gives float64 residuals, the only type the compiled robust cost takes.

    The bundle adjustment's residuals are differences of float32 samples; NONE (no brightness
    change removed) used to pass them through as float32, and its Huber cost raised TypeError.
    """
    coordinates = square_offsets(3)
    template = np.random.default_rng(6).uniform(20, 230, (5, len(coordinates)))
    values = (template - 100.0).astype(np.float32)
    projected = PhotometricProjection.of(template, model, coordinates).apply(values)
    assert projected.dtype == np.float64
    if model == PhotometricModel.NONE:
        np.testing.assert_array_equal(projected, values)


@pytest.mark.parametrize('patches', [6, 2])  # 2: each its own basis, not the first's
def test_photometric_projection_equals_the_projector_of_all_brightness_columns(patches) -> None:
    rng = np.random.default_rng(7)
    coordinates = square_offsets(4)
    template = rng.uniform(20, 230, (patches, len(coordinates)))
    u, v = (np.broadcast_to(c, template.shape) for c in coordinates.T)
    contrast = template - template.mean(axis=1, keepdims=True)
    columns = np.stack([np.ones_like(u), u, v, contrast, contrast * u, contrast * v], axis=-1)
    basis = np.linalg.qr(columns)[0]  # (N, M, 6), every column independent here
    values = rng.normal(size=(3, *template.shape))
    expected = values - np.einsum('nmk,nlk,jnl->jnm', basis, basis, values)
    projection = PhotometricProjection.of(template, PhotometricModel.GAIN_FIELD, coordinates)
    assert np.abs(projection.apply(values) - expected).max() < 1e-12
    assert np.allclose(projection.basis.transpose(0, 2, 1) @ projection.basis, np.eye(6))


def test_photometric_projections_made_at_once_and_split_equal_separate_ones() -> None:
    rng = np.random.default_rng(8)
    coordinates = square_offsets(3)
    templates = rng.uniform(20, 230, (3, 4, len(coordinates)))
    together = PhotometricProjection.of(
        np.concatenate(templates), PhotometricModel.GAIN_FIELD, coordinates
    ).split(3)
    values = rng.normal(size=(2, 4, len(coordinates)))
    for template, projection in zip(templates, together, strict=True):
        alone = PhotometricProjection.of(template, PhotometricModel.GAIN_FIELD, coordinates)
        np.testing.assert_allclose(projection.basis, alone.basis, rtol=0, atol=1e-12)
        np.testing.assert_allclose(projection.apply(values), alone.apply(values), atol=1e-12)


def test_photometric_projection_of_a_flat_template_keeps_the_bias_only() -> None:
    coordinates = square_offsets(2)
    template = np.full((2, len(coordinates)), 80.0)
    projection = PhotometricProjection.of(template, PhotometricModel.GAIN_FIELD, coordinates)
    values = np.random.default_rng(5).normal(size=template.shape)
    projected = projection.apply(values)
    assert np.all(np.isfinite(projected))
    assert np.allclose(projected.mean(axis=1), 0.0)
    u = coordinates[:, 0]
    assert np.abs(projection.apply(np.broadcast_to(u, template.shape).copy())).max() < 1e-9


def test_cv_bridge_passthrough_encodings_read_as_grey_and_opencv_colour_order() -> None:
    """cv_bridge.cv2_to_imgmsg(frame) (encoding 'passthrough') names OpenCV's type: 8UC1, 8UC3.

    The trackers refused such images ('unsupported image encoding '8UC3''); cv_bridge and
    image_view read 8UC3 as bgr8 and 8UC4 as bgra8, OpenCV's channel order.
    """
    rng = np.random.default_rng(2)
    bgra = rng.integers(0, 256, (5, 7, 4), dtype=np.uint8)
    np.testing.assert_array_equal(to_gray(bgra[..., 0], '8UC1'), bgra[..., 0])
    np.testing.assert_array_equal(to_gray(bgra[..., :3], '8UC3'), to_gray(bgra[..., :3], 'bgr8'))
    np.testing.assert_array_equal(to_gray(bgra, '8UC4'), to_gray(bgra, 'bgra8'))
