"""The numba options of the package's compiled kernels, in one place.

Every kernel is cached on disk (compiled once: on the first import after installation, or at its
first call for one declared without signatures), releases the GIL and follows numpy's error
model (a division by zero gives inf or NaN, no exception), so a diverged solve still shows as
non-finite numbers:

- :data:`EXACT`: IEEE arithmetic in the written order, for kernels that must agree with numpy bit
  for bit (the stereo tracker's ZSSD residuals);
- :data:`FAST`: sums may be reassociated (vectorised) and products fused (multiply-add), so
  results agree with numpy to rounding; infinities and NaNs are kept.
"""

from __future__ import annotations

from typing import Any

EXACT: dict[str, Any] = {'cache': True, 'nogil': True, 'error_model': 'numpy'}
FAST: dict[str, Any] = {**EXACT, 'fastmath': {'reassoc', 'contract'}}
