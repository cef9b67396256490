"""python -m fuzz: run the targets for a budget each; exit status 1 when any finding."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .corpus import SHARED
from .runner import FINDINGS, Watchdog, fuzz_target
from .targets import TARGETS


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fuzz", description=__doc__)
    parser.add_argument(
        "--target",
        action="append",
        choices=sorted(TARGETS),
        help="a target to run (repeatable; default: all)",
    )
    parser.add_argument("--seconds", type=float, help="budget per target (default 30)")
    parser.add_argument("--runs", type=int, help="executions per target (instead of time)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--no-shared", action="store_true", help="seed only from the generated files, not ../shared"
    )
    parser.add_argument("--hang-seconds", type=float, default=30.0)
    parser.add_argument("--out", type=Path, default=FINDINGS)
    args = parser.parse_args(argv)  # fmt: skip
    seconds = args.seconds if args.seconds is not None or args.runs else 30.0
    shared = not args.no_shared and SHARED.is_dir()
    watchdog = Watchdog(args.hang_seconds, args.out)
    total = 0
    for name in args.target or sorted(TARGETS):
        result = fuzz_target(
            name, seconds=seconds, runs=args.runs, seed=args.seed, shared=shared,
            watchdog=watchdog, out=args.out,
        )  # fmt: skip
        rate = result["executions"] / max(result["seconds"], 1e-9)
        print(f"{name}: {result['executions']} executions ({rate:.0f}/s), "
              f"{len(result['findings'])} findings", flush=True)  # fmt: skip
        for where, path in result["findings"].items():
            print(f"  {where}: {path}", flush=True)
        total += len(result["findings"])
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
