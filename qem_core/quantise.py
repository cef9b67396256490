"""The quantisation grid shared by the split stream and the msgpack mesh form.

One piece of code quantises for both, so that a viewer holding a level fetched as
quantised msgpack has, bit for bit, the integers the split stream's deltas refer to.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Grid"]


class Grid(NamedTuple):
    """p = origin + q * step, q an integer in [0, 2^bits - 1] per axis."""

    origin: np.ndarray  # (3,) float64
    step: np.ndarray  # (3,) float64
    bits: int

    @classmethod
    def over_box(cls, low: np.ndarray, high: np.ndarray, bits: int) -> Grid:
        """The grid of 2^bits - 1 steps from `low` to `high` (a flat axis gets step
        1 / (2^bits - 1), so every point on it quantises to 0)."""
        low = np.asarray(low, np.float64)
        high = np.asarray(high, np.float64)
        extent = np.where(high > low, high - low, 1.0)
        return cls(low, extent / ((1 << bits) - 1), bits)

    @property
    def top(self) -> np.ndarray:
        """The far corner of the box, origin + (2^bits - 1) * step."""
        return self.origin + ((1 << self.bits) - 1) * self.step

    def quantise(self, positions: np.ndarray) -> np.ndarray:
        top = (1 << self.bits) - 1
        q = np.rint((np.asarray(positions, np.float64) - self.origin) / self.step)
        return np.clip(q, 0, top).astype(np.int64)

    def dequantise(self, q: np.ndarray) -> np.ndarray:
        return self.origin + np.asarray(q, np.float64) * self.step
