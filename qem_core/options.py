"""Build options: one frozen record with safe defaults, validated once, lowered to scalars
for the kernels."""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

import numpy as np

from .errors import InvalidOptionsError

__all__ = [
    "BuildOptions",
    "ERROR_MODE_CODES",
    "NUMBER_RANGES",
    "WEIGHTING_AREA_EXPONENTS",
    "WEIGHTING_CODES",
]

Weighting = Literal["none", "sqrt_area", "area", "volume"]
ErrorMode = Literal["additive", "exact"]

# Kernel codes: the kernels take integers, not strings.
WEIGHTING_CODES = {"none": 0, "area": 1, "volume": 2, "sqrt_area": 3}
# Each weighting weights a face's plane by |N|^k, |N| its area: k by weighting.
WEIGHTING_AREA_EXPONENTS = {"none": 0.0, "sqrt_area": 0.5, "area": 1.0, "volume": 2.0}
ERROR_MODE_CODES = {"additive": 0, "exact": 1}


@dataclass(frozen=True)
class BuildOptions:
    """How `qem_core.build` simplifies.

    weighting : "none" | "sqrt_area" | "area" | "volume"
        Weight of each face's plane quadric, |N|^k for its area |N|: k = 0 (Garland-
        Heckbert), 1/2, 1, or 2 ("volume": Kim, Kim and Ko show volume optimisation is
        distance optimisation weighted by |N|^2). Border planes take the weight of a
        face of area |edge|^2. The default, "sqrt_area", measures best on the bench
        meshes: area weighting lets small, strongly curved parts (a nose, a horn tip, a
        crease's narrow faces) go cheaply, which sets the Hausdorff distance of the
        finer levels; no weighting lets big flat faces count for no more than tiny
        ones, which costs RMS (docs/performance.md).
    error_mode : "additive" | "exact"
        "additive" contracts with Q_c = Q_a + Q_b; "exact" keeps quadrics on edges and
        triangles and uses inclusion-exclusion Q_c = Q_a + Q_b - Q_ab so each original
        plane is counted once (Edelsbrunner).
    boundary_weight : float >= 0
        Weight of the plane through each open-border edge, perpendicular to its face,
        relative to a face plane of the same size. 0 lets borders erode.
    preserve_topology : bool
        Refuse edge contractions that break the link condition, pinch or close a border,
        or shrink a component below a tetrahedron. Whatever it says, no contraction may
        leave a vertex without a face (every level uses all its vertices), and pairs
        (below) never follow the link condition: joining parts is their point.
    max_face_turn_deg : float in (0, 180]
        A contraction is refused if it turns a surviving face's normal by more than this
        many degrees (from its normal before the contraction) or by more than 90 degrees
        from the normal of the original face it came from. 180 disables the per-step part.
    pair_threshold : float in [0, 1]
        Garland's t, as a fraction of the bounding-box diagonal: vertex pairs closer than
        this that share no edge are contraction candidates too, so separate parts close to
        each other may join (the face-turn limit still applies). Each vertex keeps at most
        its 8 nearest such partners. Meant for gaps shorter than the edges: a larger t
        also pairs vertices of one surface, whose joins pinch it. 0 (the default)
        disables pair contraction.
    merge_coincident : bool
        Weld vertices with exactly equal coordinates before building (STL soups).
    preserve_volume : bool
        Each contraction keeps the volume enclosed by the faces around it (a linear
        constraint on the new position, met with a Lagrange multiplier), so closed
        meshes keep their volume at every level (volume_weight only prices the change).
    uv_weight, color_weight, normal_weight : float >= 0
        Weights of the appearance attributes a mesh carries (`qem_core.build_mesh`:
        texture coordinates, vertex colours, normals) in Hoppe's quadric: an attribute
        difference of 1 costs like a distance of weight times the bounding-box
        diagonal. 0 ignores that attribute (and leaves it out of the levels).
    distance_weight : float >= 0
        Each contraction also pays for how far it moves the surface: d, the largest
        distance between the surface just before and just after it, measured at the
        points that move (the old ends against the new faces, the new vertex and the
        midpoints of the new edges against the old ones). Plane quadrics miss a move
        along their planes: the tip of a thin spike or fin (the dragon's scan seams) is
        cut back a step at a time nearly for free, since its faces' planes are parallel
        to the move and, area-weighted, tiny; d sees each step. The charge is
        distance_weight * W * (d^2 - 4 m) when positive, W the total weight of the
        planes merged and m their mean squared distance (the quadric cost over W):
        ordinary contractions, where d^2 is of the size of m, pay nothing. 0 is the
        plain quadric cost. The default, 2, keeps the Hausdorff distance within 1.1x
        the best peer's on dragon and the other bench meshes but spot, at no RMS cost,
        for about a quarter more build time on the dragon (docs/performance.md).
        Contractions whose two stars hold more than 128 faces (a vertex of very high
        degree) skip the term: its search grows with the square of the star.
    volume_weight : float >= 0
        Each contraction also pays for the volume it adds or removes: its height h, the
        volume change over the size of the star it is spread on, is charged like
        distance_weight's d, volume_weight * W * (h^2 - m / 2) when positive, and the
        new vertex is placed to minimise the quadric cost plus that charge. Plain
        quadric placement shaves a little volume off convex parts at each step, and it
        adds up on the coarse levels (Spot keeps 69 % of its volume at 17 vertices);
        fine levels, where h^2 stays below m / 2, pay nothing. The default, 3, meets the
        RMS target at every bench mesh and count, where 0 (the plain quadric cost)
        misses it at Spot's and fandisk's coarsest levels; those levels are sensitive
        to it (docs/performance.md). Ignored with preserve_volume, which keeps the
        volume exactly.
    rank_tolerance : float in [0, 1]
        Where the new vertex goes when its quadric is nearly flat in some direction: a
        direction whose eigenvalue is below this fraction of the largest is left at the
        edge's midpoint (a truncated pseudo-inverse, as Lindstrom's SVD placement), and
        the optimum is taken in the others. Larger values move vertices toward their
        edges' midpoints where that costs little error, which the split stream codes in
        fewer bytes (it predicts the midpoint: docs/formats.md); smaller ones keep
        closer to the quadric's optimum. 1e-3 (the default) is a numerical guard;
        1e-2 makes the big scans' streams 12-16 % smaller for 3-6 % more RMS error
        (docs/performance.md, "rank_tolerance").
    parallel_rounds : bool
        Contract the geometry of a mesh of more than 65536 vertices in parallel rounds
        (rounds.py): the live mesh, in z-order, is cut into parts of about 16384
        vertices, with a band of frozen vertices between them, and each part is
        contracted greedily by a loop of its own, in threads, up to a common cost; the
        sequences are merged by cost, and the next round shifts the cuts by half a part.
        The order is the greedy one except that the bands' cheap contractions, and the
        rare edge whose cost fell below the round's after it was parked, wait a round,
        and the result does not depend on the number of cores or threads. About
        2x faster on two cores (dragon: 1.89 s against 3.89 s, and 2.55 s against
        4.66 s in a slower hour, docs/performance.md).
        False: one strictly greedy sequence, as for smaller meshes, meshes with
        appearance attributes, pairs or volume preservation.
    tangent_lattice : bool
        Move each vertex that splits again (not those of the full level) along the
        surface to the nearest point of the split stream's tangent lattice, if that
        costs at most a tenth more quadric error than its optimum
        (qem_core/lattice.py). The stream codes such a vertex's place along the surface
        in units of about a sixteenth of the edge it splits into, rather than exactly:
        the streams are 8-15 % smaller, for about 1 % more RMS error
        (docs/performance.md). False keeps every vertex at its optimum, as does
        preserve_volume (a move along the surface would change the volume).
    """

    weighting: Weighting = "sqrt_area"
    error_mode: ErrorMode = "additive"
    boundary_weight: float = 1.0
    preserve_topology: bool = True
    max_face_turn_deg: float = 75.0
    pair_threshold: float = 0.0
    merge_coincident: bool = True
    preserve_volume: bool = False
    uv_weight: float = 1.0
    color_weight: float = 1.0
    normal_weight: float = 0.5
    distance_weight: float = 2.0
    volume_weight: float = 3.0
    rank_tolerance: float = 1e-3
    parallel_rounds: bool = True
    tangent_lattice: bool = True

    def __post_init__(self) -> None:
        if self.weighting not in WEIGHTING_CODES:
            raise InvalidOptionsError(
                f"weighting={self.weighting!r} is not one of {sorted(WEIGHTING_CODES)}"
            )
        if self.error_mode not in ERROR_MODE_CODES:
            raise InvalidOptionsError(
                f"error_mode={self.error_mode!r} is not one of {sorted(ERROR_MODE_CODES)}"
            )
        for name, low, high in NUMBER_RANGES:
            # Stored as a Python float: numpy scalars are accepted, and the options
            # stay JSON-serialisable (the server keeps them in its metadata).
            object.__setattr__(self, name, _checked_number(name, getattr(self, name), low, high))
        for name in ("preserve_topology", "merge_coincident", "preserve_volume",
                     "parallel_rounds", "tangent_lattice"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidOptionsError(f"{name} must be true or false")

    @classmethod
    def from_mapping(cls, values: dict[str, Any] | None) -> BuildOptions:
        """Build from a plain dict, refusing unknown keys with the list of known ones."""
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise InvalidOptionsError(
                f"unknown build option(s) {unknown}; known options are {sorted(known)}"
            )
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# The range of each numeric option (inclusive); the HTTP API's schema states them too.
NUMBER_RANGES = (
    ("boundary_weight", 0.0, 1e6),
    ("distance_weight", 0.0, 1e6),
    ("volume_weight", 0.0, 1e6),
    ("max_face_turn_deg", 1e-6, 180.0),
    ("pair_threshold", 0.0, 1.0),
    ("uv_weight", 0.0, 1e6),
    ("color_weight", 0.0, 1e6),
    ("normal_weight", 0.0, 1e6),
    ("rank_tolerance", 0.0, 1.0),
)


def _checked_number(name: str, value: object, low: float, high: float) -> float:
    """value as a float in [low, high]; any real number type (numpy's too), not a bool."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise InvalidOptionsError(f"{name} must be a number, got {value!r}")
    try:
        number = float(value)
    except OverflowError:  # an int past the float range
        number = math.inf
    if not math.isfinite(number) or not low <= number <= high:
        raise InvalidOptionsError(f"{name}={value!r} is outside [{low}, {high}]")
    return number
