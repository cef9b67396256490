"""A mutation fuzzer for every reader and decoder of qem_core.

    python -m fuzz --seconds 60            # every target, a minute each
    python -m fuzz --target qpm --runs 2000 --seed 3

Each target (``targets.py``) takes bytes and must either succeed or refuse them with a
`qem_core.QemError`: any other exception, or one input that runs past the time limit, is
a finding, saved with its traceback under ``fuzz/findings/<target>/``. Inputs come from a
seed corpus (``corpus.py``: small files of every kind written by the project's own
writers, plus the small shared meshes and earlier findings when ``../shared`` exists)
changed by the mutators of ``mutate.py``: byte-level changes for every target, and for
the msgpack-framed formats (.qpm header, split-stream frames, the msgpack mesh) changes
of the decoded values themselves, and for .qpm of its stored arrays' elements (edge values
of their types), with checksums made right again so that the input reaches the code
behind them. Run with ``NUMBA_BOUNDSCHECK=1`` and an empty ``NUMBA_CACHE_DIR`` (numba's
cache does not key on the flag), an index out of a kernel's arrays is an IndexError: a
finding, where it would otherwise corrupt memory.
"""
