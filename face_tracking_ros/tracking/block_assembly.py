"""Assembly of Gauss-Newton normal equations from per-node 3x3 blocks.

The stereo tracker's unknowns are the 3N node coordinates, ordered node-major. The eq. 5 terms
each touch two nodes, so their J^T J and J^T r arrive as small blocks; these helpers add them
into the dense (3N, 3N) matrix and (3N,) vector with one ``np.bincount`` each, which is far
faster than ``np.add.at``. (The image terms' blocks, the same every frame in number and place,
are added the same way with indices made once: ``stereo_data.SampleSet.assemble``.)
"""

from __future__ import annotations

import numpy as np

_BLOCK_ROWS, _BLOCK_COLS = np.divmod(np.arange(9), 3)


def scatter_blocks(
    rows: np.ndarray, cols: np.ndarray, blocks: np.ndarray, num_nodes: int
) -> np.ndarray:
    """Sum 3x3 blocks into a dense node-major matrix.

    Args:
        rows: (...) node index of each block's rows.
        cols: (...) node index of each block's columns (same shape as rows).
        blocks: (..., 3, 3) blocks.
        num_nodes: N.

    Returns:
        (3N, 3N) matrix with ``blocks[k]`` added at rows 3 rows[k] + (0..2) and columns
        3 cols[k] + (0..2); repeated (row, col) pairs accumulate.
    """
    size = 3 * num_nodes
    flat_rows = 3 * np.asarray(rows).reshape(-1, 1) + _BLOCK_ROWS
    flat_cols = 3 * np.asarray(cols).reshape(-1, 1) + _BLOCK_COLS
    index = (flat_rows * size + flat_cols).ravel()
    summed = np.bincount(index, weights=blocks.reshape(-1), minlength=size * size)
    return summed.reshape(size, size)


def scatter_vectors(nodes: np.ndarray, vectors: np.ndarray, num_nodes: int) -> np.ndarray:
    """Sum 3-vectors into a node-major (3N,) vector.

    Args:
        nodes: (...) node index of each vector.
        vectors: (..., 3) vectors.
        num_nodes: N.
    """
    index = (3 * np.asarray(nodes).reshape(-1, 1) + np.arange(3)).ravel()
    return np.bincount(index, weights=vectors.reshape(-1), minlength=3 * num_nodes)
