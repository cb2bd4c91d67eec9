"""One shared thread pool for the work that numpy and scipy run without the GIL (ufuncs, sparse products)."""

import os
from concurrent.futures import ThreadPoolExecutor

_POOL = None


def worker_count():
    """Threads worth using: the machine's cores, at most 8."""
    return min(os.cpu_count() or 1, 8)


def thread_map(function, items):
    """``[function(item) for item in items]``, in the shared thread pool when there is more than one item."""
    global _POOL
    if len(items) == 1:
        return [function(items[0])]
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=worker_count(), thread_name_prefix="lbc")
    return list(_POOL.map(function, items))


def map_in_rounds(function, items, before_round=None):
    """``[function(item) for item in items]``, :func:`worker_count` items at a time in the shared pool.

    ``before_round(item)``, called on the calling thread with each round's first item, reports progress and polls
    cancel between rounds, so that a cancel is seen after one round, not after them all.
    """
    results = []
    step = worker_count()
    for first in range(0, len(items), step):
        if before_round is not None:
            before_round(items[first])
        results += thread_map(function, items[first:first + step])
    return results
