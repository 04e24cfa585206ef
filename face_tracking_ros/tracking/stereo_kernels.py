"""Compiled (numba) inner loops of the stereo tracker's image terms (eq. 4, :mod:`.stereo_data`).

A pair's solve evaluates the robust residuals of ~1800 samples in 2 images against 4
templates some 7 times and forms their normal equations by node blocks some 6 times; as numpy
expressions these are a few hundred calls on small arrays whose overhead exceeds their
arithmetic (issue 9's budget: 5 ms per 640x480 pair). Each kernel is one pass over the samples,
group by group.

Samples are laid out as in :class:`~.stereo_data.SampleSet`: layout l holds G_l groups of M_l
consecutive samples from ``bounds[l]`` on. Grey levels and the ZSSD residuals stay float32 as
sampled (each group's mean is summed in float32 and subtracted in float64, as numpy does);
weights, derivatives and sums are float64. A group with a brightness ramp (a node patch,
:class:`~.stereo_data.SampleLayout`) has its least-squares ramp removed instead of its mean,
from the residuals and the Jacobian alike (the variable projection of the ramp's three
unknowns). Kernels are typed (compiled on import, or loaded from numba's on-disk cache); the
residuals use IEEE arithmetic without reassociation (those of mean-only groups equal numpy's to
the bit), the normal blocks' sums may be reassociated (vectorised).

The face-model term's arithmetic (:mod:`.action_prior`) and the image gradient carried to the
sample points (:func:`space_rows`) are here too.
"""

from __future__ import annotations

import numba
import numpy as np

from face_tracking_ros.compiled import EXACT, FAST
from face_tracking_ros.recognition.node_fit_kernels import model_jacobian_row
from face_tracking_ros.tracking.pixel_box import span

RAMP_RIDGE = 1e-6  # added to the diagonal of a brightness ramp's normal matrix (terms ~ 1)
UNIT = (1.0, 0.0, 0.0, 1.0, 0.0, 1.0)  # a ramp inverse not needed (a group's mean is removed)


@numba.njit(**EXACT)
def _block_sum(values: np.ndarray, start: int, count: int) -> float:
    """Sum of at most 128 consecutive values in numpy's order: 8 partial sums (or sequential)."""
    if count < 8:
        total = values.dtype.type(0.0)
        for i in range(start, start + count):
            total += values[i]
        return total
    p_0, p_1, p_2, p_3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    p_4, p_5, p_6, p_7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    stop = count - count % 8
    for i in range(start + 8, start + stop, 8):
        p_0 += values[i]
        p_1 += values[i + 1]
        p_2 += values[i + 2]
        p_3 += values[i + 3]
        p_4 += values[i + 4]
        p_5 += values[i + 5]
        p_6 += values[i + 6]
        p_7 += values[i + 7]
    total = ((p_0 + p_1) + (p_2 + p_3)) + ((p_4 + p_5) + (p_6 + p_7))
    for i in range(start + stop, start + count):
        total += values[i]
    return total


@numba.njit(**EXACT)
def _pairwise_sum(values: np.ndarray, start: int, count: int) -> float:
    """``values[start : start + count].sum()`` in numpy's order, in the array's precision.

    numpy sums a block of more than 128 values as the sum of its two halves (the first rounded
    down to a multiple of 8), recursively; the recursion is unrolled on an explicit stack
    (numba's cache does not hold recursive functions).
    """
    if count <= 128:
        return _block_sum(values, start, count)
    starts = np.empty(64, dtype=np.int64)
    counts = np.empty(64, dtype=np.int64)
    lefts = np.empty(64, dtype=values.dtype)  # the first half's sum, once known
    waiting = np.zeros(64, dtype=np.bool_)  # a block waiting for its second half
    depth = 0
    starts[0], counts[0], waiting[0] = start, count, False
    while True:
        if counts[depth] > 128:  # descend into the first half
            half = counts[depth] // 2
            half -= half % 8
            starts[depth + 1], counts[depth + 1] = starts[depth], half
            depth += 1
            waiting[depth] = False
            continue
        total = _block_sum(values, starts[depth], counts[depth])
        depth -= 1
        while depth >= 0 and waiting[depth]:  # both halves known: add them
            total = lefts[depth] + total
            depth -= 1
        if depth < 0:
            return total
        half = counts[depth] // 2
        half -= half % 8
        lefts[depth], waiting[depth] = total, True
        starts[depth + 1], counts[depth + 1] = starts[depth] + half, counts[depth] - half
        depth += 1
        waiting[depth] = False


@numba.njit(**EXACT)
def _ramp_inverse(
    brightness: np.ndarray, in_use: np.ndarray, first: int, stop: int
) -> tuple[float, float, float, float, float, float]:
    """Inverse of ``sum b b'`` over a group's valid samples, b its three brightness terms.

    Returned as its upper triangle (00, 01, 02, 11, 12, 22), written out (adjugate over
    determinant): a LAPACK call, or even an array, per group and image cost more than the rest
    of the kernel.
    """
    n00 = n01 = n02 = n11 = n12 = n22 = 0.0
    for s in range(first, stop):
        if in_use[s]:
            b0, b1, b2 = brightness[s, 0], brightness[s, 1], brightness[s, 2]
            n00 += b0 * b0
            n01 += b0 * b1
            n02 += b0 * b2
            n11 += b1 * b1
            n12 += b1 * b2
            n22 += b2 * b2
    n00 += RAMP_RIDGE  # valid samples on one line leave a ramp undetermined
    n11 += RAMP_RIDGE
    n22 += RAMP_RIDGE
    c00, c01, c02 = n11 * n22 - n12 * n12, n02 * n12 - n01 * n22, n01 * n12 - n02 * n11
    determinant = n00 * c00 + n01 * c01 + n02 * c02
    return (
        c00 / determinant,
        c01 / determinant,
        c02 / determinant,
        (n00 * n22 - n02 * n02) / determinant,
        (n01 * n02 - n00 * n12) / determinant,
        (n00 * n11 - n01 * n01) / determinant,
    )


@numba.njit(**EXACT)
def _remove_ramp(
    values: np.ndarray,
    brightness: np.ndarray,
    in_use: np.ndarray,
    inverse: tuple[float, float, float, float, float, float],
    first: int,
    stop: int,
) -> None:
    """Subtract from ``values[first:stop]`` their least-squares brightness ramp, in place.

    The fit is over the valid samples (``inverse`` from :func:`_ramp_inverse`); ``values`` must
    be 0 where not valid.
    """
    p0 = p1 = p2 = 0.0
    for s in range(first, stop):
        value = float(values[s])
        p0 += brightness[s, 0] * value
        p1 += brightness[s, 1] * value
        p2 += brightness[s, 2] * value
    i00, i01, i02, i11, i12, i22 = inverse
    c0 = i00 * p0 + i01 * p1 + i02 * p2
    c1 = i01 * p0 + i11 * p1 + i12 * p2
    c2 = i02 * p0 + i12 * p1 + i22 * p2
    for s in range(first, stop):
        if in_use[s]:
            values[s] = values[s] - (
                c0 * brightness[s, 0] + c1 * brightness[s, 1] + c2 * brightness[s, 2]
            )


@numba.njit(
    'Tuple((f4[:, :, ::1], i8[:, ::1], f8[:, ::1], f8[:, ::1], f8))(f4[:, :], f4[:, :, ::1], '
    'b1[:, ::1], f8[:, ::1], f8[::1], f8[::1], f8[::1], f4[::1], i8[::1], i8[::1], f8[:, ::1], '
    'i8[::1])',
    **EXACT,
)
def zssd_residuals(
    values: np.ndarray,
    templates: np.ndarray,
    valid: np.ndarray,
    coefficients: np.ndarray,
    threshold: np.ndarray,
    twice: np.ndarray,
    square: np.ndarray,
    inlier_bound: np.ndarray,
    bounds: np.ndarray,
    group_sizes: np.ndarray,
    brightness: np.ndarray,
    terms: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Robust ZSSD residuals of C sampled images against K templates each (eq. 4's terms).

    For sample s of a group and template k, ``r_k = I(s) - T_k(s) - mean_group(I - T_k)`` over
    the group's valid samples (0 where not valid); its Huber weight is ``min(1, k_s / |r_k|)``
    and its loss ``r^2`` within k_s, ``2 k_s |r| - k_s^2`` beyond. A group with more than one
    brightness term has the least-squares fit of ``I - T_k`` by those terms (a brightness ramp
    over the patch) removed instead of its mean, when it has more valid samples than terms.

    Args:
        values: (C, S) float32 grey levels I (any strides).
        templates: (C, K, S) float32 templates T_k.
        valid: (C, S) the samples in use.
        coefficients: (K, S) coefficients a_k >= 0.
        threshold: (S,) Huber thresholds k_s.
        twice: (S,) 2 k_s.
        square: (S,) k_s^2.
        inlier_bound: (S,) float32 largest float32 <= k_s (a float32 |r| is within k_s exactly
            when it is within this).
        bounds: (L + 1,) first sample of every layout, then S.
        group_sizes: (L,) M_l.
        brightness: (S, 3) brightness terms of every sample: 1, u, v over a patch grid.
        terms: (sum G_l,) brightness terms of each group: 1 (its mean only) or 3.

    Returns:
        ``(differences, counts, weight, weighted_residual, cost)``: (C, K, S) float32 r_k,
        (C, sum G_l) valid samples of each group (layout after layout), (C, S)
        ``sum_k a_k w_k``, (C, S) ``sum_k a_k w_k r_k`` and the cost ``sum a_k rho(r_k)``.
    """
    images, count, size = templates.shape
    differences = np.empty((images, count, size), dtype=np.float32)
    groups = 0
    for layout in range(group_sizes.size):
        groups += (bounds[layout + 1] - bounds[layout]) // group_sizes[layout]
    counts = np.zeros((images, groups), dtype=np.int64)
    weight = np.zeros((images, size))
    weighted_residual = np.zeros((images, size))
    losses = np.empty((images, count, size))
    masked = np.empty(size, dtype=np.float32)  # one group's I - T_k where valid, else 0
    for c in range(images):
        grey, in_use = values[c], valid[c]
        group = 0
        for layout in range(group_sizes.size):
            members = group_sizes[layout]
            for first in range(bounds[layout], bounds[layout + 1], members):
                stop = first + members
                for s in range(first, stop):
                    counts[c, group] += in_use[s]
                divisor = float(max(counts[c, group], 1))
                ramp = terms[group] > 1 and counts[c, group] > terms[group]
                inverse = _ramp_inverse(brightness, in_use, first, stop) if ramp else UNIT
                for k in range(count):
                    template, difference = templates[c, k], differences[c, k]
                    for s in range(first, stop):
                        difference[s] = grey[s] - template[s]
                        masked[s] = difference[s] if in_use[s] else np.float32(0.0)
                    if ramp:
                        _remove_ramp(masked, brightness, in_use, inverse, first, stop)
                        for s in range(first, stop):
                            difference[s] = masked[s]
                        continue
                    mean = float(_pairwise_sum(masked, first, members)) / divisor
                    for s in range(first, stop):
                        centred = np.float32(difference[s] - mean)
                        difference[s] = centred if in_use[s] else np.float32(0.0)
                group += 1
        total_weight, total_residual = weight[c], weighted_residual[c]
        for k in range(count):  # summed over k in order, as numpy sums a middle axis
            difference, coefficient, loss = differences[c, k], coefficients[k], losses[c, k]
            for s in range(size):
                magnitude = abs(difference[s])
                robust = threshold[s] / magnitude  # inf at |r| = 0: weight 1
                if robust > 1.0:
                    robust = 1.0
                weighted = coefficient[s] * robust
                total_weight[s] += weighted
                total_residual[s] += weighted * difference[s]
                inlier = float(magnitude * magnitude)
                outlier = twice[s] * magnitude - square[s]
                loss[s] = coefficient[s] * (inlier if magnitude <= inlier_bound[s] else outlier)
    cost = _pairwise_sum(losses.ravel(), 0, losses.size)
    return differences, counts, weight, weighted_residual, cost


@numba.njit('f8[:, :, ::1](f8[:, :, :], f8[:, :, ::1], f4[:, :, ::1], b1[:, ::1])', **FAST)
def space_rows(
    projections: np.ndarray, homogeneous: np.ndarray, gradient: np.ndarray, valid: np.ndarray
) -> np.ndarray:
    """The image gradient carried to the camera-frame points: ``h = (d pi / d X_c)' grad I``.

    With ``x = (P X)_(1, 2) / (P X)_3`` (eq. 2), ``d x / d X = (P_(1, 2) - x P_3) / (P X)_3``, so
    ``h = (P_(1, 2)' g - (g . x) P_3) / (P X)_3``: the change of a sample's grey level per metre
    of its point's motion (0 where the sample is not valid).

    Args:
        projections: (C, 3, 3+) the cameras' P (its left 3x3 part is used), px per m.
        homogeneous: (C, 3, S) ``P X`` of the samples' points, homogeneous pixels.
        gradient: (C, 2, S) image gradient at their pixels, grey levels / px.
        valid: (C, S) the samples in use.

    Returns:
        (C, 3, S) h, grey levels / m.
    """
    cameras, _, size = homogeneous.shape
    rows = np.zeros((cameras, 3, size))
    for c in range(cameras):
        for s in range(size):
            if not valid[c, s]:
                continue
            g_x, g_y = float(gradient[c, 0, s]), float(gradient[c, 1, s])
            inverse_depth = 1.0 / homogeneous[c, 2, s]
            along = (g_x * homogeneous[c, 0, s] + g_y * homogeneous[c, 1, s]) * inverse_depth
            for a in range(3):
                rows[c, a, s] = (
                    projections[c, 0, a] * g_x
                    + projections[c, 1, a] * g_y
                    - projections[c, 2, a] * along
                ) * inverse_depth
    return rows


@numba.njit(
    'Tuple((f8[:, :, ::1], f8[:, ::1]))(f8[:, :, ::1], b1[:, ::1], f8[:, ::1], f8[:, ::1], '
    'i8[:, :], f8[:, ::1], i8, i8, f8[:, ::1], i8[::1])',
    **FAST,
)
def node_normal_blocks(
    rows: np.ndarray,
    valid: np.ndarray,
    weight: np.ndarray,
    weighted_residual: np.ndarray,
    counts: np.ndarray,
    slot_weights: np.ndarray,
    first: int,
    members: int,
    brightness: np.ndarray,
    terms: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton blocks ``J' W J`` and ``J' W r`` of one layout's groups, summed over images.

    The Jacobian of a sample with respect to slot node j is ``b_j h`` with h its image
    gradient carried to the point (eq. 2, :func:`space_rows`), minus the
    group's mean over its valid samples (ZSSD), or minus its fit by the group's brightness
    terms, as :func:`zssd_residuals` removes from the residuals.

    Args:
        rows: (C, 3, S) h of every sample (0 where not valid), grey levels per m.
        valid: (C, S) the samples in use.
        weight: (C, S) ``sum_k a_k w_k``.
        weighted_residual: (C, S) ``sum_k a_k w_k r_k``.
        counts: (C, G) valid samples of each of the layout's groups.
        slot_weights: (k, G M) barycentric weights b_j of the layout's samples.
        first: the layout's first sample.
        members: M, samples per group.
        brightness: (S, 3) brightness terms of every sample (of all layouts).
        terms: (G,) brightness terms of each of the layout's groups: 1 or 3.

    Returns:
        ``(blocks, vectors)``: (G, 3k, 3k) and (G, 3k).
    """
    images, groups = counts.shape
    slots = slot_weights.shape[0]
    width = 3 * slots
    blocks = np.zeros((groups, width, width))
    vectors = np.zeros((groups, width))
    jacobian = np.empty((width, members))  # one group's rows in one image
    for c in range(images):
        for g in range(groups):
            start = first + g * members
            divisor = float(max(counts[c, g], 1))
            ramp = terms[g] > 1 and counts[c, g] > terms[g]
            in_use = valid[c, start : start + members]
            shape = brightness[start : start + members]
            inverse = _ramp_inverse(shape, in_use, 0, members) if ramp else UNIT
            for j in range(slots):
                for a in range(3):
                    row = jacobian[3 * j + a]
                    for m in range(members):
                        row[m] = slot_weights[j, g * members + m] * rows[c, a, start + m]
                    if ramp:
                        _remove_ramp(row, shape, in_use, inverse, 0, members)
                        continue
                    mean = _pairwise_sum(row, 0, members) / divisor
                    for m in range(members):
                        if valid[c, start + m]:
                            row[m] -= mean
            weights = weight[c, start : start + members]
            residuals = weighted_residual[c, start : start + members]
            for i in range(width):
                row = jacobian[i]
                total = 0.0
                for m in range(members):
                    total += residuals[m] * row[m]
                vectors[g, i] += total
                for other in range(i, width):
                    column = jacobian[other]
                    total = 0.0
                    for m in range(members):
                        total += row[m] * weights[m] * column[m]
                    blocks[g, i, other] += total
                    if other > i:
                        blocks[g, other, i] += total
    return blocks, vectors


@numba.njit(**EXACT)
def _box_of(x_32: np.ndarray, y_32: np.ndarray, box: np.ndarray) -> int:
    """How many of the (S,) float32 pixels are not finite; their least and greatest x, y in box.

    ``box`` (4,) is left as it is for no pixels (meaningless unless every pixel is finite).
    """
    non_finite = 0
    for s in range(x_32.size):
        non_finite += ~(np.isfinite(x_32[s]) & np.isfinite(y_32[s]))
    if x_32.size:
        box[0], box[1] = span(x_32)
        box[2], box[3] = span(y_32)
    return non_finite


@numba.njit(
    'Tuple((f4[:, :, ::1], f4[:, :, ::1], b1[:, ::1], f4[:, ::1], b1))(f8[:, :, ::1], f8[::1], '
    'b1[::1], '
    'f4[::1], f4[::1], f8, f8, f8)',
    **EXACT,
)
def stencil_maps(
    homogeneous: np.ndarray,
    depth: np.ndarray,
    mask: np.ndarray,
    shift_x: np.ndarray,
    shift_y: np.ndarray,
    low: float,
    high_x: float,
    high_y: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """The pixels of C images' samples as stencil maps for ``cv2.remap``, validity and boxes.

    Sample s lies at ``x = P_1 X / P_3 X``, ``y = P_2 X / P_3 X`` (eq. 2) of each image; its
    map holds the float32 x and y plus each stencil shift (float32 sums,
    :func:`~face_tracking_ros.imaging.sampling.sample_stencils`). It is valid when in the mask,
    in front of the camera (``depth > 0``) and within ``[low, high]`` in x and y. The box
    spans every sample's pixel, valid or not (``cv2.remap`` reads them all), for the pyramid to
    make the image over (:meth:`~face_tracking_ros.imaging.ImagePyramid.level_reaching`).

    Args:
        homogeneous: (C, 3, S) ``P X`` of the samples in each image, homogeneous pixels.
        depth: (S,) the samples' camera z, m.
        mask: (S,) the samples in use.
        shift_x: (J,) float32 stencil shifts along x, px.
        shift_y: (J,) float32 stencil shifts along y, px.
        low: the smallest x and y inside the image, px.
        high_x: the largest x inside, px.
        high_y: the largest y inside, px.

    Returns:
        ``(maps_x, maps_y, valid, boxes, finite)``: (C, J, S) float32 maps, (C, S) valid
        samples, (C, 4) float32 least and greatest x, then y, of each image's pixels (an empty
        box for no samples; meaningless unless finite), and whether every float32 x and y is
        finite.
    """
    images, _, size = homogeneous.shape
    shifts = shift_x.size
    maps_x = np.empty((images, shifts, size), dtype=np.float32)
    maps_y = np.empty((images, shifts, size), dtype=np.float32)
    valid = np.empty((images, size), dtype=np.bool_)
    boxes = np.empty((images, 4), dtype=np.float32)
    boxes[:] = np.array([0.0, -1.0, 0.0, -1.0], dtype=np.float32)  # nothing read
    x_32 = np.empty(size, dtype=np.float32)
    y_32 = np.empty(size, dtype=np.float32)
    non_finite = 0
    for c in range(images):
        for s in range(size):  # loops without branches, so that they vectorise
            x = homogeneous[c, 0, s] / homogeneous[c, 2, s]
            y = homogeneous[c, 1, s] / homogeneous[c, 2, s]
            x_32[s], y_32[s] = x, y
            inside = (x >= low) & (y >= low) & (x <= high_x) & (y <= high_y)
            valid[c, s] = inside & (depth[s] > 0.0) & mask[s]
        non_finite += _box_of(x_32, y_32, boxes[c])
        for j in range(shifts):
            for s in range(size):
                maps_x[c, j, s] = x_32[s] + shift_x[j]
                maps_y[c, j, s] = y_32[s] + shift_y[j]
    return maps_x, maps_y, valid, boxes, non_finite == 0


@numba.njit('Tuple((f4[:, ::1], f4[:, ::1], f4[:, ::1], b1))(f8[:, :, ::1])', **EXACT)
def pixel_maps(homogeneous: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """The float32 pixels of C images' samples, for ``cv2.remap``, and the boxes they span.

    Sample s lies at ``x = P_1 X / P_3 X``, ``y = P_2 X / P_3 X`` (eq. 2) of each image,
    rounded to float32 as ``cv2.remap`` reads it (:func:`stencil_maps` without the stencil).

    Args:
        homogeneous: (C, 3, S) ``P X`` of the samples in each image, homogeneous pixels.

    Returns:
        ``(x, y, boxes, finite)``: (C, S) float32 x and y, (C, 4) float32 least and greatest x,
        then y, of each image's pixels (an empty box for no samples; meaningless unless
        finite), and whether every x and y is finite.
    """
    images, _, size = homogeneous.shape
    x_32 = np.empty((images, size), dtype=np.float32)
    y_32 = np.empty((images, size), dtype=np.float32)
    boxes = np.empty((images, 4), dtype=np.float32)
    boxes[:] = np.array([0.0, -1.0, 0.0, -1.0], dtype=np.float32)  # nothing read
    non_finite = 0
    for c in range(images):
        for s in range(size):
            x_32[c, s] = homogeneous[c, 0, s] / homogeneous[c, 2, s]
            y_32[c, s] = homogeneous[c, 1, s] / homogeneous[c, 2, s]
        non_finite += _box_of(x_32[c], y_32[c], boxes[c])
    return x_32, y_32, boxes, non_finite == 0


@numba.njit(
    [
        f'Tuple((f8[:, ::1], f8[::1]))(UniTuple(f8[:, :, ::1], {layouts}), '
        f'UniTuple(f8[:, ::1], {layouts}), i8[::1], i8[::1], i8)'
        for layouts in (1, 2)  # node patches alone, or with the face texture
    ],
    **EXACT,
)
def scatter_sums(
    blocks: tuple[np.ndarray, ...],
    vectors: tuple[np.ndarray, ...],
    block_index: np.ndarray,
    vector_index: np.ndarray,
    size: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The layouts' node blocks and vectors summed into a (size, size) matrix and (size,) vector.

    Entry e of the blocks (of the vectors), raveled layout after layout, goes to flat index
    ``block_index[e]`` (``vector_index[e]``), added in that order: ``np.bincount``'s sums, to
    the bit.
    """
    matrix = np.zeros(size * size)
    entry = 0
    for block in blocks:
        for value in block.ravel():
            matrix[block_index[entry]] += value
            entry += 1
    vector = np.zeros(size)
    entry = 0
    for part in vectors:
        for value in part.ravel():
            vector[vector_index[entry]] += value
            entry += 1
    return matrix.reshape(size, size), vector


@numba.njit(**EXACT)
def _pixel(projection: np.ndarray, point: np.ndarray, axis: int) -> float:
    """Pixel coordinate ``axis`` (0: x, 1: y) of a point (3,) through a projection P (3, 4)."""
    x, y, z = point[0], point[1], point[2]
    depth = projection[2, 0] * x + projection[2, 1] * y + projection[2, 2] * z + projection[2, 3]
    row = projection[axis]
    return (row[0] * x + row[1] * y + row[2] * z + row[3]) / depth


@numba.njit('f8(f8[:, :, ::1], f8[:, ::1], f8[:, ::1])', **EXACT)
def largest_motion(projections: np.ndarray, nodes: np.ndarray, moved: np.ndarray) -> float:
    """The largest pixel motion of N points between two estimates, in any of C images (NaN if any).

    Args:
        projections: (C, 3, 4) the images' P of eq. 2.
        nodes: (N, 3) the points at the first estimate, m.
        moved: (N, 3) the points at the second, m.

    Returns:
        ``max |x_2 - x_1|`` over the points, both pixel coordinates and the images, px.
    """
    largest = 0.0
    for c in range(projections.shape[0]):
        for a in range(2):
            for i in range(nodes.shape[0]):
                before = _pixel(projections[c], nodes[i], a)
                motion = abs(_pixel(projections[c], moved[i], a) - before)
                if np.isnan(motion):
                    return np.nan
                largest = max(largest, motion)
    return largest


@numba.njit(**EXACT)
def _contrast(
    values: np.ndarray,
    valid: np.ndarray,
    first: int,
    members: int,
    masked: np.ndarray,
    centred: np.ndarray,
) -> float:
    """RMS of a group's valid float32 values about their mean (NaN without any), as numpy's.

    ``masked`` (M,) float32 and ``centred`` (M,) float64 are scratch.
    """
    count = 0
    for m in range(members):
        count += valid[first + m]
        masked[m] = values[first + m] if valid[first + m] else np.float32(0.0)
    mean = float(_pairwise_sum(masked, 0, members)) / float(max(count, 1))
    for m in range(members):
        centred[m] = float(masked[m]) - mean if valid[first + m] else 0.0
        centred[m] *= centred[m]
    return np.sqrt(_pairwise_sum(centred, 0, members) / float(count))


@numba.njit(
    'Tuple((f8[:, ::1], f8[:, ::1], f8[:, ::1]))(f4[:, :], f4[:, :], f4[:, :], b1[:, ::1], '
    'i8[:, ::1], i8[::1], i8[::1])',
    **EXACT,
)
def group_summaries(
    differences: np.ndarray,
    leading: np.ndarray,
    values: np.ndarray,
    valid: np.ndarray,
    counts: np.ndarray,
    bounds: np.ndarray,
    group_sizes: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every group's RMS residual; the template's and image's contrast of the first layout's.

    numpy's arithmetic in numpy's order (float32 pairwise sums of float32 values, float64
    sums of float64 ones), for :func:`~.stereo_data.group_statistics`: the RMS is
    ``sqrt(sum r^2 / count)`` of the float32 residuals r, a contrast
    :func:`~.stereo_data.group_contrast`'s (NaN for a group without valid samples).

    Args:
        differences: (C, S) float32 leading ZSSD residuals (0 where not valid).
        leading: (C, S) float32 leading template T_0 of each image.
        values: (C, S) float32 grey levels of the images.
        valid: (C, S) the samples in use.
        counts: (C, sum G_l) valid samples of each group, layout after layout.
        bounds: (L + 1,) first sample of every layout, then S.
        group_sizes: (L,) M_l.

    Returns:
        ``(rms, contrast, image_contrast)``: (C, sum G_l), (C, G_0) and (C, G_0).
    """
    images, groups = counts.shape
    first_groups = (bounds[1] - bounds[0]) // group_sizes[0]
    rms = np.empty((images, groups))
    contrast = np.empty((images, first_groups))
    image_contrast = np.empty((images, first_groups))
    squares = np.empty(differences.shape[1], dtype=np.float32)
    masked = np.empty(group_sizes[0], dtype=np.float32)
    centred = np.empty(group_sizes[0])
    for c in range(images):
        group = 0
        for layout in range(group_sizes.size):
            members = group_sizes[layout]
            for first in range(bounds[layout], bounds[layout + 1], members):
                for s in range(first, first + members):
                    squares[s] = differences[c, s] * differences[c, s]
                total = _pairwise_sum(squares, first, members)
                rms[c, group] = np.sqrt(float(total) / float(counts[c, group]))
                group += 1
        members = group_sizes[0]
        for g in range(first_groups):
            first = bounds[0] + g * members
            contrast[c, g] = _contrast(leading[c], valid[c], first, members, masked, centred)
            image_contrast[c, g] = _contrast(values[c], valid[c], first, members, masked, centred)
    return rms, contrast, image_contrast


@numba.njit('f8[::1](f4[:, :], b1[:, ::1], i8, i8)', **EXACT)
def stereo_contrast(
    values: np.ndarray, valid: np.ndarray, groups: int, members: int
) -> np.ndarray:
    """(G,) RMS of the left - right difference of each of the first G groups about its mean.

    Over the samples valid in both images (NaN for a group without any), as
    :func:`~.stereo_data.group_contrast` of the float32 differences, for
    :func:`~.stereo_occlusion.stereo_disagreement`.

    Args:
        values: (2, S) float32 grey levels of the left and right images (any strides).
        valid: (2, S) the samples in use.
        groups: G, the groups of M consecutive samples from sample 0 (the node patches).
        members: M.
    """
    size = groups * members
    difference = np.empty(size, dtype=np.float32)
    both = np.empty(size, dtype=np.bool_)
    for s in range(size):
        difference[s] = values[0, s] - values[1, s]
        both[s] = valid[0, s] and valid[1, s]
    masked = np.empty(members, dtype=np.float32)
    centred = np.empty(members)
    contrast = np.empty(groups)
    for g in range(groups):
        contrast[g] = _contrast(difference, both, g * members, members, masked, centred)
    return contrast


@numba.njit(
    'void(f8[:, :], f8[:, :], f8[:, ::1], f8, i8[:, ::1], f8[:, ::1], i8, f8[:, ::1])', **EXACT
)
def layout_points(
    nodes: np.ndarray,
    offsets: np.ndarray,
    field: np.ndarray,
    scale: float,
    gather: np.ndarray,
    weights: np.ndarray,
    start: int,
    points: np.ndarray,
) -> None:
    """One layout's sample points ``sum_k b_k X^(n_k) + o``, with the node patches' deformation.

    Sample s of the layout is sample ``start + s`` of the set; the first S_p samples of the set
    (the node patches) have the offset ``o + scale * field`` (see
    :meth:`~.stereo_data.SampleSet.points`). The sum over the slots is in slot order.

    Args:
        nodes: (N, 3) nodes X, m.
        offsets: (3, S) offsets o of all samples of the set, m.
        field: (3, S_p) the deformation of the first S_p samples, m (S_p = 0: none).
        scale: its factor (2^l on pyramid level l).
        gather: (k, S_l) node index n_k of each slot of the layout's samples.
        weights: (k, S_l) barycentric weight b_k of each slot (unused for k = 1).
        start: the layout's first sample in the set.
        points: (3, S) the set's points, whose ``start : start + S_l`` are written, m.
    """
    slots, size = gather.shape
    deformed = field.shape[1]
    for a in range(3):
        for s in range(size):
            placed = nodes[gather[0, s], a]
            if slots > 1:
                placed *= weights[0, s]
                for k in range(1, slots):
                    placed += nodes[gather[k, s], a] * weights[k, s]
            offset = offsets[a, start + s]
            if start + s < deformed:
                offset += scale * field[a, start + s]
            points[a, start + s] = placed + offset


# The face-model term (:mod:`.action_prior`): M = R (B + A alpha) + t, its refit and its
# Gauss-Newton terms (6 + q unknowns, 3N rows), some thirty small numpy calls a trial point as
# numpy expressions. The model and its difference to the nodes are exact (an unmoved mesh costs
# exactly nothing); the normal matrices and the Hessian equal numpy's to rounding.


@numba.njit(
    'Tuple((f8[:, ::1], f8[:, ::1]))(f8[:, ::1], f8[:, :, ::1], f8[::1], f8[:, ::1])', **EXACT
)
def model_shape(
    base: np.ndarray, action_basis: np.ndarray, theta: np.ndarray, rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(shape, nodes)``: (N, 3) B + A alpha in the face frame and M = R shape + t, m.

    Args:
        base: (N, 3) base shape B, m.
        action_basis: (N, 3, q) A.
        theta: (6 + q,) omega, t, alpha.
        rotation: (3, 3) R(omega).
    """
    count, _, actions = action_basis.shape
    shape = np.empty((count, 3))
    nodes = np.empty((count, 3))
    for n in range(count):
        for a in range(3):
            value = 0.0
            for j in range(actions):
                value += action_basis[n, a, j] * theta[6 + j]
            shape[n, a] = base[n, a] + value
        for a in range(3):
            nodes[n, a] = (
                rotation[a, 0] * shape[n, 0]
                + rotation[a, 1] * shape[n, 1]
                + rotation[a, 2] * shape[n, 2]
            ) + theta[3 + a]
    return shape, nodes


@numba.njit('Tuple((f8[::1], f8))(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1])', **EXACT)
def model_difference(
    motion: np.ndarray, nodes: np.ndarray, first_model: np.ndarray, row_weights: np.ndarray
) -> tuple[np.ndarray, float]:
    """``(difference, cost)``: (3N,) (X - X(1)) - (M - M(1)) and its weighted square sum.

    Args:
        motion: (N, 3) X - X(1), m.
        nodes: (N, 3) M, m.
        first_model: (N, 3) M(1), m.
        row_weights: (3N,) lambda_i of every coordinate.
    """
    difference = (motion - (nodes - first_model)).ravel()
    cost = 0.0
    for r in range(difference.size):
        cost += difference[r] * (row_weights[r] * difference[r])
    return difference, cost


@numba.njit(
    'Tuple((f8[:, ::1], f8[:, ::1], f8[:, ::1]))(f8[:, ::1], f8[:, ::1], f8[:, :, ::1], '
    'f8[:, :, ::1], f8[::1], f8)',
    **FAST,
)
def model_normal(
    shape: np.ndarray,
    rotation: np.ndarray,
    d_rotation: np.ndarray,
    action_basis: np.ndarray,
    row_weights: np.ndarray,
    damping: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(W J, J' W J, damped)`` of J = dM / d(omega, t, alpha) (3N, 6 + q).

    ``damped`` is J' W J with its diagonal times ``1 + damping``.

    Args:
        shape: (N, 3) B + A alpha, m.
        rotation: (3, 3) R(omega).
        d_rotation: (3, 3, 3) dR / d omega_k.
        action_basis: (N, 3, q) A.
        row_weights: (3N,) lambda_i of every coordinate.
        damping: the relative Levenberg damping of ``damped``.
    """
    count, _, actions = action_basis.shape
    unknowns = 6 + actions
    jacobian = np.empty((3 * count, unknowns))
    for n in range(count):
        for a in range(3):
            model_jacobian_row(
                shape[n], rotation, d_rotation, action_basis, n, a, jacobian[3 * n + a]
            )
    weighted = np.empty_like(jacobian)
    for row in range(3 * count):
        for c in range(unknowns):
            weighted[row, c] = jacobian[row, c] * row_weights[row]
    normal = np.zeros((unknowns, unknowns))
    for row in range(3 * count):
        for c in range(unknowns):
            for e in range(c, unknowns):
                normal[c, e] += jacobian[row, c] * weighted[row, e]
    for c in range(unknowns):
        for e in range(c):
            normal[c, e] = normal[e, c]
    damped = normal.copy()
    for c in range(unknowns):
        damped[c, c] *= 1.0 + damping
    return weighted, normal, damped


@numba.njit('f8[::1](f8[:, ::1], f8[:, ::1], f8[::1], f8[::1])', **FAST)
def model_step(
    weighted: np.ndarray, damped: np.ndarray, difference: np.ndarray, theta: np.ndarray
) -> np.ndarray:
    """(6 + q,) theta moved by the Gauss-Newton step ``damped^-1 (W J)' difference``."""
    unknowns = theta.size
    gradient = np.zeros(unknowns)
    for row in range(difference.size):
        for c in range(unknowns):
            gradient[c] += weighted[row, c] * difference[row]
    return theta + np.linalg.solve(damped, gradient)


@numba.njit('f8[:, ::1](f8[:, ::1], f8[:, ::1], f8[::1])', **FAST)
def model_hessian(weighted: np.ndarray, normal: np.ndarray, row_weights: np.ndarray) -> np.ndarray:
    """(3N, 3N) W - W J (J' W J)^-1 J' W, the Hessian of the variable projection.

    As W - K K' with K = W J L^-T, ``J' W J = L L'`` (Cholesky): one product of BLAS.

    Raises:
        LinAlgError: if J' W J is not positive definite.
    """
    rows, unknowns = weighted.shape
    lower = np.linalg.cholesky(normal)
    solved = np.empty((unknowns, rows))  # K' = L^-1 (W J)', forward substitution
    for c in range(unknowns):
        for r in range(rows):
            value = weighted[r, c]
            for k in range(c):
                value -= lower[c, k] * solved[k, r]
            solved[c, r] = value / lower[c, c]
    hessian = -np.dot(solved.T, solved)
    for r in range(rows):
        hessian[r, r] += row_weights[r]
    return hessian
