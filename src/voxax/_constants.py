"""Numerical bounds shared by the Python checks and the C++ kernels.

The kernels define the same values (`csrc/`); a test checks that both sides agree.
"""

from __future__ import annotations

__all__ = ["MAX_ABS_COORDINATE", "MIN_CELL_VOLUME", "MAX_CELL_VOLUME", "PAIR_BUDGET"]

#: Largest accepted vertex coordinate magnitude: |N|^2 of a face normal cannot overflow.
MAX_ABS_COORDINATE = 1e75
#: Range of accepted grid cell volumes (area in 2D).
MIN_CELL_VOLUME = 1e-300
MAX_CELL_VOLUME = 1e300
#: Number of (point, face) pairs evaluated at once by the chunked pure-JAX loops.
PAIR_BUDGET = 1 << 20
