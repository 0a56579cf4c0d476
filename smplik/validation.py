"""Input validation shared by the public entry points."""

from __future__ import annotations

from typing import Any

import numpy as np


def finite_array(value: Any, shape: tuple[int, ...], where: str, error: type[Exception] = ValueError) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` with no NaN/inf, else ``error`` naming ``where``."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{where}: must be numbers, got {value!r:.60}.") from None
    if arr.shape != shape:
        raise error(f"{where}: has shape {arr.shape}; expected {shape}.")
    if not np.isfinite(arr).all():
        raise error(f"{where}: contains NaN or inf.")
    return arr
