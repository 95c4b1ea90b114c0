"""Array type aliases shared by the package.

:data:`FloatArray`   a float64 NumPy array (``numpy.typing.NDArray[numpy.float64]``)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: A float64 NumPy array of any shape.
FloatArray = NDArray[np.float64]

__all__ = ["FloatArray"]
