"""One process-wide thread pool for the work that releases the GIL (onnxruntime sessions, numba kernels)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

_POOL: tuple[int, ThreadPoolExecutor] | None = None


def shared_pool(workers: int) -> ThreadPoolExecutor:
    """A shared thread pool with at least ``workers`` threads (created, or grown, on first use)."""
    global _POOL
    if _POOL is None or _POOL[0] < workers:
        _POOL = (workers, ThreadPoolExecutor(max_workers=workers, thread_name_prefix="smplik"))
    return _POOL[1]


def run_spread(run: Callable[[int, int], None], bounds: Sequence[int], threads: int) -> None:
    """``run(lo, hi)`` for every pair of consecutive ``bounds``, spread over ``threads`` threads.

    Chunk ``i`` goes to thread ``i % threads`` (each thread takes its chunks in order); with one thread,
    or one chunk, everything runs in the caller. The first exception raised by a chunk is re-raised.
    """
    pairs = [(int(lo), int(hi)) for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]
    workers = max(1, min(threads, len(pairs)))
    if workers == 1:
        for lo, hi in pairs:
            run(lo, hi)
        return

    def lane(k: int) -> None:
        for lo, hi in pairs[k::workers]:
            run(lo, hi)

    futures = [shared_pool(workers).submit(lane, k) for k in range(workers)]
    for fut in futures:
        fut.result()
