"""The quantisation grids shared by the split stream and the msgpack mesh form.

One piece of code quantises for both, so that a viewer holding a level fetched as
quantised msgpack has, bit for bit, the integers the split stream's deltas refer to:
`Grid` for positions, `AttributeGrid` for the wedges' appearance values.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["AttributeGrid", "Grid", "QuantisedWedges"]


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
        return cls(low, _steps(low, high, (1 << bits) - 1), bits)

    @classmethod
    def from_values(cls, values, bits: int) -> Grid:
        """The grid of a stream's ``grid`` (origin x y z, step x y z); ValueError when
        it does not describe one: 6 finite numbers, positive steps, a finite far corner
        (with a step of 0 every vertex would land on the origin; past the float range
        on infinity)."""
        values = np.asarray(values, np.float64)
        if values.shape != (6,):
            raise ValueError("a grid is 6 numbers: origin x y z, step x y z")
        _check_grid(values[:3], values[3:], (1 << bits) - 1)
        return cls(values[:3], values[3:], bits)

    def check(self) -> Grid:
        """This grid, or ValueError when it is no grid (as `from_values`): a box read
        from a file can span more than float64 steps over (its far corner at infinity)."""
        _check_grid(self.origin, self.step, (1 << self.bits) - 1)
        return self

    @property
    def top(self) -> np.ndarray:
        """The far corner of the box, origin + (2^bits - 1) * step."""
        return self.origin + ((1 << self.bits) - 1) * self.step

    def quantise(self, positions: np.ndarray) -> np.ndarray:
        return _quantise(positions, self.origin, self.step, (1 << self.bits) - 1)

    def dequantise(self, q: np.ndarray) -> np.ndarray:
        return self.origin + np.asarray(q, np.float64) * self.step


class AttributeGrid(NamedTuple):
    """Grids for appearance values (in the attribute's units: UVs, colours in [0, 1],
    normals), one per column: v = origin + q * step, q an integer in [0, 2^bits - 1]
    with the bits of the column's attribute.

    names, widths, bits : per attribute, in value-row order; origin, step : (k,) per
    column, k = sum(widths).
    """

    names: tuple[str, ...]
    widths: tuple[int, ...]
    bits: tuple[int, ...]
    origin: np.ndarray
    step: np.ndarray

    @classmethod
    def over_box(cls, names, widths, bits, low: np.ndarray, high: np.ndarray) -> AttributeGrid:
        """The grid of 2^bits - 1 steps per column from `low` to `high` (k,)."""
        grid = cls(
            tuple(names),
            tuple(int(w) for w in widths),
            tuple(int(b) for b in bits),
            np.asarray(low, np.float64),
            np.zeros(0),
        )
        return grid._replace(step=_steps(grid.origin, high, grid.q_max))

    @property
    def q_max(self) -> np.ndarray:
        """(k,) int64, the largest integer of each column."""
        return np.repeat((1 << np.asarray(self.bits, np.int64)) - 1, self.widths)

    def quantise(self, values: np.ndarray) -> np.ndarray:
        return _quantise(values, self.origin, self.step, self.q_max)

    def dequantise(self, q: np.ndarray) -> np.ndarray:
        return self.origin + np.asarray(q, np.float64) * self.step

    def to_dict(self) -> dict:
        """The grid as msgpack-ready lists (the stream's ``wedge_grid``)."""
        return {
            "names": list(self.names),
            "widths": list(self.widths),
            "bits": list(self.bits),
            "origin": self.origin.tolist(),
            "step": self.step.tolist(),
        }

    @classmethod
    def from_dict(cls, values: dict) -> AttributeGrid:
        """The grid of a ``to_dict`` map; ValueError (or TypeError, KeyError) when it
        does not describe one: widths 1..4, bits 1..16, k finite origins and positive
        finite steps."""
        names = tuple(str(name) for name in values["names"])
        widths = tuple(_integer(w, 1, 4) for w in values["widths"])
        bits = tuple(_integer(b, 1, 16) for b in values["bits"])
        origin = np.asarray(values["origin"], np.float64)
        step = np.asarray(values["step"], np.float64)
        k = sum(widths)
        if not len(names) == len(widths) == len(bits) or k == 0:
            raise ValueError("names, widths and bits must be as many, at least one")
        if origin.shape != (k,) or step.shape != (k,):
            raise ValueError(f"origin and step must hold {k} numbers")
        grid = cls(names, widths, bits, origin, step)
        _check_grid(origin, step, grid.q_max)
        return grid


class QuantisedWedges(NamedTuple):
    """The appearance of a level as a client refines it: the wedge of every face corner,
    face_wedges (m, 3) int, and the wedges' values on ``grid``, values (W, k) int64."""

    grid: AttributeGrid
    face_wedges: np.ndarray
    values: np.ndarray


def _integer(value, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"{value!r} is not an integer in [{low}, {high}]")
    return value


def _check_grid(origin: np.ndarray, step: np.ndarray, q_max) -> None:
    """ValueError unless origin and step are finite, the steps positive and the far
    corner origin + q_max * step finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        top = origin + q_max * step
    if not (np.isfinite(origin).all() and (step > 0).all() and np.isfinite(top).all()):
        raise ValueError("origin and step must be finite, steps positive, the far corner finite")


def _steps(low: np.ndarray, high: np.ndarray, top) -> np.ndarray:
    """Step of a grid of `top` steps per axis from low to high (1 / top on a flat axis,
    so every point on it quantises to 0)."""
    high = np.asarray(high, np.float64)
    # At least the smallest normal float64: a box a few subnormals across would give a
    # step of 0 (positions then quantised to NaN), where this puts them all at its origin.
    with np.errstate(over="ignore"):  # a span past float64 gives inf: `check` refuses it
        span = np.where(high > low, high - low, 1.0)
    return np.maximum(span / top, np.finfo(np.float64).tiny)


def _quantise(values, origin: np.ndarray, step: np.ndarray, top) -> np.ndarray:
    q = np.rint((np.asarray(values, np.float64) - origin) / step)
    return np.clip(q, 0, top).astype(np.int64)
