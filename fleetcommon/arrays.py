"""The numpy array types that columns, kernels and maps are annotated with, declared once for the
daemon and the clients."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]
