"""Array aliases shared by the modules (shapes are documented where they are used)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.floating]
CountArray = npt.NDArray[np.integer]
BoolArray = npt.NDArray[np.bool_]
Shape2D = tuple[int, int]

__all__ = ["FloatArray", "CountArray", "BoolArray", "Shape2D"]
