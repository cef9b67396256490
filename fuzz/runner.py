"""Running a target: its seeds, then mutants of its corpus for a budget; findings saved."""

from __future__ import annotations

import hashlib
import os
import random
import threading
import time
import traceback
import warnings
from pathlib import Path

import qem_core

from .corpus import seeds
from .targets import TARGETS

__all__ = ["FINDINGS", "Watchdog", "fuzz_target"]

FINDINGS = Path(__file__).resolve().parent / "findings"


class Watchdog:
    """Ends the process when one execution runs past ``limit`` seconds (a hang: numba
    kernels cannot be interrupted), after saving the input that hung."""

    def __init__(self, limit: float, out: Path) -> None:
        self.limit = limit
        self.out = out
        self.started: float | None = None
        self.input = b""
        self.target = ""
        threading.Thread(target=self._watch, daemon=True).start()

    def _watch(self) -> None:
        while True:
            time.sleep(min(1.0, self.limit / 4))
            started = self.started
            if started is not None and time.monotonic() - started > self.limit:
                path = _save(self.out, self.target, self.input, f"hang: over {self.limit} s\n")
                print(f"{self.target}: HANG, input saved to {path}", flush=True)
                os._exit(2)


def _save(out: Path, target: str, data: bytes, report: str) -> Path:
    folder = out / target
    folder.mkdir(parents=True, exist_ok=True)
    name = hashlib.sha1(data).hexdigest()[:12]
    (folder / f"{name}.bin").write_bytes(data)
    (folder / f"{name}.txt").write_text(report)
    return folder / f"{name}.bin"


def fuzz_target(
    name: str,
    *,
    seconds: float | None = None,
    runs: int | None = None,
    seed: int = 0,
    shared: bool = True,
    watchdog: Watchdog | None = None,
    out: Path = FINDINGS,
) -> dict:
    """Run one target; returns its executions, seconds and findings (distinct by the
    place the exception came from)."""
    target = TARGETS[name]
    corpus = seeds(name, shared=shared)
    rng = random.Random(seed)
    findings: dict[str, str] = {}
    watchdog = watchdog or Watchdog(30.0, out)
    watchdog.target = name

    def execute(data: bytes) -> None:
        watchdog.input = data
        watchdog.started = time.monotonic()
        try:
            with warnings.catch_warnings():
                # as the tests run: a numpy warning on a hostile file is a missed check
                warnings.simplefilter("error")
                target.run(data)
        except qem_core.QemError:
            pass
        except Exception as error:  # the finding: anything but a refusal
            frame = traceback.extract_tb(error.__traceback__)[-1]
            where = f"{type(error).__name__} at {Path(frame.filename).name}:{frame.lineno}"
            if where not in findings:
                findings[where] = str(_save(out, name, data, traceback.format_exc()))
        finally:
            watchdog.started = None

    for data in corpus:  # the seeds first (this also loads the kernels)
        execute(data)
    executions = 0
    start = time.monotonic()
    while (runs is None or executions < runs) and (
        seconds is None or time.monotonic() - start < seconds
    ):
        data = target.mutate(rng.choice(corpus), rng, corpus)
        execute(data)
        executions += 1
        if executions % 64 == 0 and len(corpus) < 256 and rng.random() < 0.05:
            corpus.append(data)  # keep some mutants: deeper changes over time
    return {"executions": executions, "seconds": time.monotonic() - start, "findings": findings}
