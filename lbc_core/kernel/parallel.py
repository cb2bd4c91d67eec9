"""One shared thread pool for the work that numpy and scipy run without the GIL (ufuncs, sparse products), and how
busy the machine is for it (the threads runnable now, else the load average)."""

import contextlib
import functools
import math
import os
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor

from threadpoolctl import threadpool_limits

_POOL = None
# The one-minute load average's time constant, in seconds (an exponential average of the runnable threads).
LOAD_TIME_CONSTANT = 60.0
# This process's recent binds, which the load average still holds: (end, wall seconds, CPU seconds) of each.
_OWN_WORK = deque(maxlen=16)
_COUNTING = threading.local()
# Readings of the runnable threads averaged for the busy factor, and the seconds between them.
RUNNABLE_SAMPLES, RUNNABLE_SPACING = 10, 0.002
# Row chunks of map_row_chunks come in multiples of this many, whatever the threads (at most 8, worker_count).
CHUNKS_PER_ROUND = 8
# The cores a bind keeps busy on average, its threads' parallel parts and serial parts together (121-142 % CPU on
# 2 cores: bench/RESULTS.md, "The busy factor counted now").
BIND_CORES = 1.3


def worker_count():
    """Threads worth using: the machine's cores, at most 8."""
    return min(os.cpu_count() or 1, 8)


def busy_factor():
    """How many times an idle machine's time work takes now: the threads other jobs keep runnable share the cores
    with ours. Counted now where the system says (:func:`runnable_others`), else from the one-minute load average
    less the part this process's own finished binds left in it (:func:`own_load`); 1 where neither is known."""
    others = runnable_others()
    if others is None:
        try:
            others = max(0.0, os.getloadavg()[0] - own_load())
        except (AttributeError, OSError):
            return 1.0
    return max(1.0, (others + min(BIND_CORES, worker_count())) / (os.cpu_count() or 1))


def runnable_others(path="/proc/loadavg", tasks="/proc/self/task", samples=RUNNABLE_SAMPLES,
                    spacing=RUNNABLE_SPACING):
    """Threads of other processes runnable now: the mean of ``samples`` readings ``spacing`` seconds apart of Linux's
    count (the fourth field of /proc/loadavg) less this process's own runnable threads (``tasks``: its threads'
    folders, whose ``stat`` gives their state; a BLAS pool spinning after a product is no other job); None where
    ``path`` cannot be read. The load average lags a minute behind: it still counts jobs that just ended and not yet
    those that just began (bench/RESULTS.md, "The busy factor counted now")."""
    total = 0
    try:
        for sample in range(samples):
            if sample:
                time.sleep(spacing)
            with open(path) as loadavg:
                total += int(loadavg.read().split()[3].split("/")[0])
            total -= _running_threads(tasks)
    except (OSError, ValueError, IndexError):
        return None
    return max(0.0, total / samples)


def _running_threads(tasks):
    """How many of the threads under ``tasks`` (a /proc/PID/task folder) are running or runnable (state R)."""
    running = 0
    for thread in os.listdir(tasks):
        try:
            with open(os.path.join(tasks, thread, "stat")) as stat:
                running += stat.read().rpartition(")")[2].split()[0] == "R"
        except OSError:  # a thread that ended meanwhile
            continue
    return running


def own_load(now=None):
    """The part of the one-minute load average that this process's recent binds (:func:`counted_in_load`) still make,
    in threads: each kept its CPU rate (CPU seconds per second) of threads runnable while it ran, which the average
    took in as 1 - exp(-duration / τ) of it and has decayed by exp(-elapsed / τ) since (τ = LOAD_TIME_CONSTANT).
    ``now``: a time.monotonic() reading (default: now)."""
    now = time.monotonic() if now is None else now
    total = 0.0
    for end, seconds, cpu in _OWN_WORK:
        if seconds > 0:
            taken_in = -math.expm1(-seconds / LOAD_TIME_CONSTANT)
            total += cpu / seconds * taken_in * math.exp(-max(0.0, now - end) / LOAD_TIME_CONSTANT)
    return total


def counted_in_load(function):
    """``function`` with its wall and CPU time recorded for :func:`own_load` (once, however deeply such functions
    call one another)."""

    @functools.wraps(function)
    def counted(*args, **kwargs):
        if getattr(_COUNTING, "active", False):
            return function(*args, **kwargs)
        _COUNTING.active = True
        wall, cpu = time.monotonic(), time.process_time()
        try:
            return function(*args, **kwargs)
        finally:
            end = time.monotonic()
            _OWN_WORK.append((end, end - wall, time.process_time() - cpu))
            _COUNTING.active = False

    return counted


@contextlib.contextmanager
def one_blas_thread():
    """BLAS on one thread inside (every thread of the process): for work whose many small products each of our
    threads makes (the smooth fit's blocks, the thinning's): OpenBLAS's own threads on them took 1.7 times the CPU and
    more wall time on a busy machine (bench/RESULTS.md, "The bind outside the solve, cheaper")."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def thread_map(function, items):
    """``[function(item) for item in items]``, in the shared thread pool when there is more than one item."""
    global _POOL
    if len(items) == 1:
        return [function(items[0])]
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=worker_count(), thread_name_prefix="lbc")
    return list(_POOL.map(function, items))


def map_row_chunks(function, m, most_rows, before_round=None):
    """``function(rows)`` over consecutive slices of ``range(m)``, one per thread at a time, in order.

    The slices depend on ``m`` and ``most_rows`` alone, never on the threads: a chunk's rows are computed together
    (padded to its longest row), so slices that followed the cores gave other weights on another machine. They are
    of equal size (at most ``most_rows``), CHUNKS_PER_ROUND or a multiple of it, so that 1, 2, 4 or 8 threads idle
    through no short last round (Suzanne's 48,612 rows in 16,384-row chunks: eight of 6077).
    ``before_round(start)``, called on the calling thread with each round's first row, reports progress and polls
    cancel, so that a cancel is seen after one round, not after them all.
    """
    threads = worker_count()
    count = CHUNKS_PER_ROUND * -(-m // (CHUNKS_PER_ROUND * most_rows))
    size = max(-(-m // count), 1) if m else 1
    starts = range(0, m, size)
    results = []
    for first in range(0, len(starts), threads):
        if before_round is not None:
            before_round(starts[first])
        results += thread_map(lambda start: function(slice(start, min(start + size, m))), starts[first:first + threads])
    return results
