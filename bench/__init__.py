"""Benchmarks of qem-lod against peer simplifiers.

Entry points (run from the repository root):

- ``python -m bench.simplify_quality``: geometric error at equal vertex count, qem-lod's
  progressive mesh against meshoptimizer, fast_simplification, pyfqmr, pymeshlab and open3d.
- ``python -m bench.build_speed``: time and peak memory of the whole qem-lod forest build,
  beside one meshoptimizer and one pymeshlab simplification of the same mesh.
- ``python -m bench.build_profile``: a hot build's CPU time by numba kernel (Linux perf).

Every timed call runs in a child process (`bench.measure`), so peak RSS is the call's own.
See bench/README.md.
"""
