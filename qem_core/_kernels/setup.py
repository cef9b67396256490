"""Initial state of the contraction loop: vertex, edge and border quadrics, first costs."""

import numba
import numpy as np
from numba import types
from numba.typed import Dict

from . import heap as heap_ops
from .contract import edge_cost, edge_key
from .quadrics import QUADRIC_SIZE, boundary_quadric


def _fill_border_quadrics(vertices, border_edges, border_faces, face_normals, weighting,
                          boundary_weight, out):
    """out[i] = constraint plane of border edge i (its endpoints, its one face)."""
    for i in range(border_edges.shape[0]):
        boundary_quadric(
            vertices, border_edges[i, 0], border_edges[i, 1],
            face_normals[border_faces[i]], weighting, boundary_weight, out[i],
        )


fill_border_quadrics = numba.njit(cache=True)(_fill_border_quadrics)


def _make_edge_slots(edges, n_vertices):
    """Typed dict edge key -> row of the edge quadric array (exact mode)."""
    slots = Dict.empty(key_type=types.int64, value_type=types.int64)
    for i in range(edges.shape[0]):
        slots[edge_key(edges[i, 0], edges[i, 1], n_vertices)] = i
    return slots


make_edge_slots = numba.njit(cache=True)(_make_edge_slots)


def _fill_heap(vertices, vertex_quadrics, edge_slot, edge_quadrics, heap_entries, heap_size,
               edges, exact, rank_tolerance):
    """Put every edge in the heap with its cost, then order it once (O(E))."""
    quadric = np.zeros(QUADRIC_SIZE)
    position = np.zeros(3)
    scratch = np.zeros(1)
    for i in range(edges.shape[0]):
        a, b = edges[i, 0], edges[i, 1]
        cost = edge_cost(vertices, vertex_quadrics, edge_slot, edge_quadrics, a, b, exact,
                         rank_tolerance, quadric, position)
        heap_ops.put(heap_entries, i, heap_ops.cost_key(cost, scratch), a, b, 0, 0)
    heap_size[0] = edges.shape[0]
    heap_ops.heapify(heap_entries, heap_size)


fill_heap = numba.njit(cache=True)(_fill_heap)
