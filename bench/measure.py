"""Time and peak memory of one call, measured in a fresh child process.

Every benchmark goes through `measure_in_child`, so all figures mean the same thing:

- **time**: `time.perf_counter` around the call alone, in seconds, once per run; the
  child imports the modules and unpickles the input before the first run, so neither is
  counted. `median_s` is the median over the runs.
- **peak RSS**: the child's resident-set high-water mark after the runs, in bytes. Just
  before the first run the child resets it (`/proc/self/clear_refs`, Linux >= 4.0), so
  the peak is the one reached *during* the calls, not while the input was unpickled; it
  still includes the resident input and the imported libraries. `rss_increase_bytes` is
  that peak minus the resident set just before the first call: what the call added.

  The mark is read as `VmHWM` from /proc/self/status. `resource.getrusage(...).ru_maxrss`
  is the fallback only: in a child started by fork/vfork + exec it never reports less
  than the *parent's* peak at the time of the exec (Linux carries the old address
  space's mark over into `signal->maxrss`), so a small call measured from a large
  harness would show the harness's memory.
- **CPU time**: `time.process_time` around the call, once per run: user + system time of
  every thread of the child. Over the wall time it is the number of cores the call kept
  busy on average, and over the machine's core count it bounds how fast the call could
  run there, whatever its scheduling.

Run as ``python -m bench.measure REQUEST RESPONSE``, this module is the child: it reads a
pickled request, runs it, and writes a pickled response. Functions are pickled by
reference, so they must live in an importable module (not ``__main__``).
"""

from __future__ import annotations

import gc
import importlib
import os
import pickle
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["ChildCallError", "ChildMeasurement", "measure_in_child", "median_of_runs"]

_REPO_ROOT = Path(__file__).resolve().parents[1]
_PAGE_SIZE = os.sysconf("SC_PAGE_SIZE")


class ChildCallError(RuntimeError):
    """The measured call raised, crashed or ran out of time in the child process."""


@dataclass(frozen=True)
class ChildMeasurement:
    """What one `measure_in_child` call measured.

    times_s : wall time of each run of the call, seconds.
    cpu_times_s : CPU time (user + system, all threads) of each run, seconds.
    rss_before_bytes : resident set of the child just before the first run.
    peak_rss_bytes : peak resident set during the runs (see the module docstring).
    peak_covers_setup : True where the high-water mark could not be reset, so the peak
        may have been reached while loading the input rather than during the call.
    result : what `then(result_of_last_run, *then_args)` returned, or the last run's
        result when no `then` was given.
    """

    times_s: tuple[float, ...]
    cpu_times_s: tuple[float, ...]
    rss_before_bytes: int
    peak_rss_bytes: int
    peak_covers_setup: bool
    result: Any

    @property
    def median_s(self) -> float:
        return median_of_runs(self.times_s)

    @property
    def rss_increase_bytes(self) -> int:
        return max(0, self.peak_rss_bytes - self.rss_before_bytes)


def median_of_runs(times_s: Sequence[float]) -> float:
    """Median of run times (seconds); raises ValueError on an empty sequence."""
    if not times_s:
        raise ValueError("median_of_runs needs at least one run time")
    return float(statistics.median(times_s))


def measure_in_child(
    function: Callable[..., Any],
    args: Sequence[Any] = (),
    *,
    runs: int = 1,
    preload: Sequence[str] = (),
    before: Callable[..., Any] | None = None,
    before_args: Sequence[Any] = (),
    then: Callable[..., Any] | None = None,
    then_args: Sequence[Any] = (),
    env: Mapping[str, str] | None = None,
    timeout_s: float | None = None,
) -> ChildMeasurement:
    """Run `function(*args)` `runs` times in a fresh Python process and measure it.

    function, before, then : top-level functions of importable modules (pickled by
        reference).
    args : pickled to the child; numpy arrays travel as they are.
    preload : module names imported in the child before the clock starts (the lazy
        imports of an adapter, e.g. "pymeshlab"), so import time is not counted.
    before : called untimed with `before_args` after the imports and before the clock
        starts, e.g. to let a JIT compile on a small input first.
    then : called untimed on the last run's result, in the child, with `then_args`; its
        return value is what comes back. Use it for results that cannot be pickled or are
        too large to send (e.g. a progressive mesh, from which only some levels are
        wanted).
    env : extra environment variables for the child (e.g. NUMBA_CACHE_DIR).
    timeout_s : wall-clock limit for the whole child, seconds; None for no limit.

    Raises ChildCallError with the child's traceback if the call raised, or with the
    exit status and the tail of its output if the child died.
    """
    if runs < 1:
        raise ValueError(f"runs={runs} must be at least 1")
    for named in (function, before, then):
        if named is not None and getattr(named, "__module__", "__main__") == "__main__":
            raise ValueError(
                f"{named!r} is defined in __main__; move it to a module under bench/ so "
                "the child process can import it"
            )
    child_env = dict(os.environ)
    child_env["PYTHONPATH"] = os.pathsep.join(
        [str(_REPO_ROOT), *filter(None, [child_env.get("PYTHONPATH")])]
    )
    child_env.update(env or {})
    request = {
        "function": function,
        "args": tuple(args),
        "runs": int(runs),
        "preload": tuple(preload),
        "before": before,
        "before_args": tuple(before_args),
        "then": then,
        "then_args": tuple(then_args),
    }
    with tempfile.TemporaryDirectory(prefix="qem-bench-") as work_dir:
        request_path = Path(work_dir) / "request.pickle"
        response_path = Path(work_dir) / "response.pickle"
        with open(request_path, "wb") as request_file:
            pickle.dump(request, request_file, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            completed = subprocess.run(
                [sys.executable, "-m", "bench.measure", str(request_path), str(response_path)],
                cwd=_REPO_ROOT,
                env=child_env,
                capture_output=True,
                text=True,
                timeout=timeout_s,
            )
        except subprocess.TimeoutExpired as expired:
            raise ChildCallError(
                f"{_name(function)} ran past its limit of {timeout_s} s in the child process"
            ) from expired
        if completed.returncode != 0 or not response_path.exists():
            tail = (completed.stdout + completed.stderr)[-2000:]
            raise ChildCallError(
                f"child process for {_name(function)} exited with status "
                f"{completed.returncode}; output tail:\n{tail}"
            )
        with open(response_path, "rb") as response_file:
            response = pickle.load(response_file)
    if "error" in response:
        raise ChildCallError(f"{_name(function)} raised in the child process:\n{response['error']}")
    return ChildMeasurement(**response)


def _name(function: Callable[..., Any]) -> str:
    return f"{getattr(function, '__module__', '?')}.{getattr(function, '__qualname__', function)}"


def _resident_bytes() -> int:
    """Current resident set of this process, bytes (Linux /proc/self/statm)."""
    with open("/proc/self/statm", encoding="ascii") as statm:
        return int(statm.read().split()[1]) * _PAGE_SIZE


def _peak_resident_bytes() -> int:
    """This process's resident high-water mark, bytes: VmHWM, else ru_maxrss (KiB)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _reset_peak_rss() -> bool:
    """Reset this process's RSS high-water mark; False where the kernel does not allow it."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as clear_refs:
            clear_refs.write("5")
        return True
    except OSError:
        return False


def _run_request(request: dict[str, Any]) -> dict[str, Any]:
    for module_name in request["preload"]:
        importlib.import_module(module_name)
    if request["before"] is not None:
        request["before"](*request["before_args"])
    function, args = request["function"], request["args"]
    gc.collect()
    peak_reset = _reset_peak_rss()
    rss_before = _resident_bytes()
    times_s, cpu_times_s = [], []
    result = None
    for _ in range(request["runs"]):
        result = None  # let the previous result go before the next run
        start, cpu_start = time.perf_counter(), time.process_time()
        result = function(*args)
        times_s.append(time.perf_counter() - start)
        cpu_times_s.append(time.process_time() - cpu_start)
    peak_rss = _peak_resident_bytes()
    if request["then"] is not None:
        result = request["then"](result, *request["then_args"])
    return {
        "times_s": tuple(times_s),
        "cpu_times_s": tuple(cpu_times_s),
        "rss_before_bytes": rss_before,
        "peak_rss_bytes": max(peak_rss, rss_before),
        "peak_covers_setup": not peak_reset,
        "result": result,
    }


def _child_main(request_path: str, response_path: str) -> None:
    try:
        with open(request_path, "rb") as request_file:
            request = pickle.load(request_file)
        response = _run_request(request)
    except BaseException:  # report everything, including SystemExit from the callee
        response = {"error": traceback.format_exc()}
    with open(response_path, "wb") as response_file:
        pickle.dump(response, response_file, protocol=pickle.HIGHEST_PROTOCOL)


if __name__ == "__main__":
    _child_main(sys.argv[1], sys.argv[2])
