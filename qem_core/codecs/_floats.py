"""Widening float32 values read from a file to float64."""

from __future__ import annotations

import numpy as np

__all__ = ["widened"]


def widened(values) -> np.ndarray:
    """``values`` as float64. A signalling NaN in a file sets the invalid-operation flag
    when it is converted, which numpy reports as a RuntimeWarning; the value is a NaN
    either way, and mesh validation refuses NaN coordinates with a message."""
    with np.errstate(invalid="ignore"):
        return np.asarray(values).astype(np.float64)
