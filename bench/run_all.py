"""Every benchmark with its defaults, as `make bench` runs it.

    python -m bench.run_all

The quality sweep over all seven meshes with 3 runs per peer call, the build-speed
comparison on the dragon, lod(n) from a loaded .qpm against the peers on the dragon, the
split-stream size of all seven meshes, and the service figures on the dragon (a real
server on 127.0.0.1; wrk for the load run where installed). Takes well over an hour on a
2-core machine, most of it the peers on igea and dragon. Exit status: non-zero if any
benchmark reports a problem (including qem_core.build not existing yet).
"""

from __future__ import annotations

import sys

from . import (
    build_speed,
    lod_speed,
    read_speed,
    service,
    simplify_quality,
    stream_serving,
    stream_size,
)


def main() -> int:
    statuses = [
        simplify_quality.main([]),
        build_speed.main([]),
        lod_speed.main([]),
        stream_size.main([]),
        service.main([]),
        stream_serving.main([]),
        read_speed.main([]),
    ]
    return max(statuses)


if __name__ == "__main__":
    sys.exit(main())
