"""The detector's worker threads: compiled kernels (which release the GIL) run on them.

``ARTCAL_THREADS`` sets how many (default 2, at most the CPU count); 1 runs
everything on the caller's thread. Results do not depend on it. The pool is one per process,
shared by every detector, created on first use under a lock (afresh in a forked child);
concurrent.futures joins its threads at interpreter exit.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

__all__ = ["run_all", "split_even", "threads"]

_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _forget_pools_in_child() -> None:
    # A forked child inherits the pools but not their threads: work handed to them would wait
    # forever (a multiprocessing worker detecting after its parent had). Start afresh.
    global _POOLS_LOCK
    _POOLS.clear()
    _POOLS_LOCK = threading.Lock()


os.register_at_fork(after_in_child=_forget_pools_in_child)
MIN_RUN = 20_000  # work units (samples) below which a thread costs more than it saves


def threads() -> int:
    """Threads the kernels may use: ``ARTCAL_THREADS``, else 2 (at most the CPU count)."""
    env = os.environ.get("ARTCAL_THREADS", "")
    return max(1, int(env) if env.isdigit() else min(2, os.cpu_count() or 1))


def split_even(items: np.ndarray, work: np.ndarray) -> list[np.ndarray]:
    """``items`` (N,) in consecutive runs of about equal ``work`` (N,), 4 runs per thread.

    More runs than threads: a thread that the OS puts aside (a busy machine) holds
    up only its current run while the others take the rest. One run when the work
    is small or there is one thread.
    """
    total = float(np.sum(work))
    parts = min(4 * threads(), int(total // MIN_RUN)) if threads() > 1 else 1
    if parts <= 1:
        return [items]
    cut = np.searchsorted(np.cumsum(work), np.arange(1, parts) * total / parts)
    return [c for c in np.split(items, cut) if len(c)]


def run_all(fn: Callable[[np.ndarray], Any], runs: list[np.ndarray]) -> None:
    """fn(run) for every run, on the worker threads when there are several runs."""
    if len(runs) == 1:
        fn(runs[0])
        return
    n = threads()
    with _POOLS_LOCK:  # two detecting threads (live tiers) may arrive here at once
        pool = _POOLS.get(n)
        if pool is None:
            pool = _POOLS[n] = ThreadPoolExecutor(n, thread_name_prefix="detect kernels")
    list(pool.map(fn, runs))  # list(): re-raises a worker's exception here
