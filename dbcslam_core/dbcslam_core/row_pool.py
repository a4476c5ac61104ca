"""Threads over the rows of the filter's compiled kernels.

The compiled kernels of the step (`kernels`, `step_kernels`) treat the rows of the state
arrays (particles, or a friction bank's copies) independently and release the GIL
(`nogil=True`), so contiguous ranges of rows can run on several cores at once. `RowPool`
splits the rows into ranges of about equal work (`row_chunks`), runs the first range in the
calling thread and the others on a small thread pool, and returns the kernels' results in
range order. Every row is computed by the same code whatever the split, so the outputs do
not depend on the number of threads (bit for bit; `tests/core/test_row_pool.py`).

Threads rather than numba's `parallel=True`: no threading layer to choose (GNU OpenMP is not
fork-safe, and the discrepancy analysis forks worker processes), the caller decides the
split (work per range, not rows per range) and the pool is re-created after a fork.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from dbcslam_core.errors import ModelError

__all__ = ["MAX_AUTO_THREADS", "RowPool", "resolve_threads", "row_chunks", "usable_cpus"]

T = TypeVar("T")
IntArray = npt.NDArray[np.int64]

MAX_AUTO_THREADS = 4
"""The most threads `resolve_threads(None)` picks (the kernels gain little beyond)."""


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask; `os.cpu_count()` elsewhere)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def resolve_threads(threads: int | None) -> int:
    """The thread count of a `FilterConfig.threads` value: None = the usable CPUs, at most
    `MAX_AUTO_THREADS`; an int >= 1 as given."""
    if threads is None:
        return min(usable_cpus(), MAX_AUTO_THREADS)
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        msg = f"threads must be None (automatic) or an integer >= 1, got {threads!r}"
        raise ModelError(msg)
    return threads


def row_chunks(
    n_rows: int, parts: int, *, starts: IntArray | None = None, min_work: int = 1
) -> list[tuple[int, int]]:
    """Split rows 0 .. n_rows into at most `parts` contiguous ranges [lo, hi) of about equal
    work: the entries of the rows when `starts` (n_rows + 1,) gives row p the entries
    starts[p] .. starts[p + 1], else one unit per row. No range holds less than `min_work`
    units (fewer ranges instead); an empty problem is one empty range."""
    if n_rows <= 0:
        return [(0, 0)]
    total = n_rows if starts is None else int(starts[-1] - starts[0])
    n = max(1, min(parts, total // max(min_work, 1), n_rows))
    if n == 1:
        return [(0, n_rows)]
    if starts is None:
        cuts = [(k * n_rows) // n for k in range(n + 1)]
    else:
        targets = starts[0] + (np.arange(1, n) * total) // n
        inner = np.searchsorted(starts, targets, side="left").tolist()
        cuts = [0, *inner, n_rows]
    bounds = [(lo, hi) for lo, hi in itertools.pairwise(cuts) if hi > lo]
    return bounds or [(0, n_rows)]


class RowPool:
    """A pool of `threads` - 1 worker threads (the caller is the other one) for row kernels.

    `map(fn, bounds)` calls fn(lo, hi) for every range, the first in the calling thread,
    and returns the results in range order; an exception of any range is raised in the
    caller. The worker threads start on first use and are re-created in a forked child."""

    def __init__(self, threads: int | None = None) -> None:
        self._threads = resolve_threads(threads)
        self._executor: ThreadPoolExecutor | None = None
        self._pid = os.getpid()
        self._lock = threading.Lock()

    @property
    def threads(self) -> int:
        """Threads a step's kernels may use (the caller's included)."""
        return self._threads

    def chunks(
        self, n_rows: int, *, starts: IntArray | None = None, min_work: int = 1
    ) -> list[tuple[int, int]]:
        """`row_chunks` into at most `threads` ranges."""
        return row_chunks(n_rows, self._threads, starts=starts, min_work=min_work)

    def map(self, fn: Callable[[int, int], T], bounds: Sequence[tuple[int, int]]) -> list[T]:
        """fn(lo, hi) for each range of bounds, in order (see the class docstring)."""
        if len(bounds) <= 1:
            return [fn(*b) for b in bounds]
        executor = self._ensure_executor()
        futures = [executor.submit(fn, lo, hi) for lo, hi in bounds[1:]]
        try:
            first = fn(*bounds[0])
        finally:  # never leave a range running past the call
            rest = [f.result() for f in futures]
        return [first, *rest]

    def close(self) -> None:
        """Stop the worker threads (a later `map` starts them again)."""
        with self._lock:
            if self._executor is not None and self._pid == os.getpid():
                self._executor.shutdown(wait=True)
            self._executor = None

    def _ensure_executor(self) -> ThreadPoolExecutor:
        with self._lock:
            if self._pid != os.getpid():  # a forked child: the parent's threads are not here
                self._executor = None
                self._pid = os.getpid()
            if self._executor is None:
                self._executor = ThreadPoolExecutor(
                    max_workers=max(self._threads - 1, 1), thread_name_prefix="dbcslam-rows"
                )
            return self._executor

    def __getstate__(self) -> dict[str, object]:
        """Pickled without its threads (a copy starts its own)."""
        return {"threads": self._threads}

    def __setstate__(self, state: dict[str, object]) -> None:
        threads = state["threads"]
        self._threads = resolve_threads(threads if isinstance(threads, int) else None)
        self._executor = None
        self._pid = os.getpid()
        self._lock = threading.Lock()
