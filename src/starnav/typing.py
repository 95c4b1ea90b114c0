"""Array type aliases shared by the package.

:data:`FloatArray`   a float64 NumPy array (``numpy.typing.NDArray[numpy.float64]``)
:data:`Float32Array` a float32 NumPy array (images, charge and signal frames)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: A float64 NumPy array of any shape.
FloatArray = NDArray[np.float64]
#: A float32 NumPy array of any shape (the detector chain's frames).
Float32Array = NDArray[np.float32]

__all__ = ["Float32Array", "FloatArray"]
