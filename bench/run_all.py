"""Every benchmark with its defaults, as `make bench` runs it.

    python -m bench.run_all

The quality sweep over all seven meshes with 3 runs per peer call, then the build-speed
comparison on the dragon. Takes about an hour on a 2-core machine, most of it the peers
on igea and dragon. Exit status: non-zero if either benchmark reports a problem
(including qem_core.build not existing yet).
"""

from __future__ import annotations

import sys

from . import build_speed, simplify_quality


def main() -> int:
    quality_status = simplify_quality.main([])
    speed_status = build_speed.main([])
    return max(quality_status, speed_status)


if __name__ == "__main__":
    sys.exit(main())
