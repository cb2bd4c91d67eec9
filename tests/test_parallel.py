"""The shared thread pool: row chunks in full rounds of one chunk per thread."""

import threading

import numpy as np
import pytest

from lbc_core.kernel import parallel


@pytest.mark.parametrize("threads, m, most", [(2, 48_612, 16_384), (2, 64_130, 16_384), (3, 10, 4), (2, 1, 100),
                                              (8, 0, 100)])
def test_row_chunks_cover_the_rows_in_order_in_equal_slices_and_full_rounds(monkeypatch, threads, m, most):
    monkeypatch.setattr(parallel, "worker_count", lambda: threads)
    rounds = []
    chunks = parallel.map_row_chunks(lambda rows: rows, m, most, rounds.append)
    assert [index for rows in chunks for index in range(rows.start, rows.stop)] == list(range(m))
    sizes = [rows.stop - rows.start for rows in chunks]
    assert all(size <= most for size in sizes)
    assert len(set(sizes[:-1])) <= 1 and sizes[-1:] <= sizes[:1]  # equal slices, the last one at most as long
    assert rounds == [chunk.start for chunk in chunks[::threads]]
    assert len(chunks) <= threads * len(rounds) and (m == 0 or len(chunks) > threads * (len(rounds) - 1))


@pytest.mark.parametrize("m, most", [(48_612, 16_384), (810, 4096), (10, 4)])
def test_row_chunks_are_the_same_slices_whatever_the_threads(monkeypatch, m, most):
    """A chunk's rows are reduced together, padded to its longest row: slices that followed the cores gave other
    weights on a machine with other cores."""
    layouts = []
    for threads in (1, 2, 3, 8):
        monkeypatch.setattr(parallel, "worker_count", lambda: threads)
        layouts.append([(rows.start, rows.stop) for rows in parallel.map_row_chunks(lambda rows: rows, m, most)])
    assert all(layout == layouts[0] for layout in layouts)


def test_row_chunks_run_on_several_threads():
    seen = set()
    barrier = threading.Barrier(min(parallel.worker_count(), 2), timeout=5)  # two chunks, one round

    def work(rows):
        seen.add(threading.get_ident())
        barrier.wait()  # two chunks must be running at once for this to return
        return rows

    parallel.map_row_chunks(work, 2, 1)
    assert len(seen) == min(parallel.worker_count(), 2)


def test_the_busy_factor_counts_the_other_jobs_against_the_cores(monkeypatch):
    monkeypatch.setattr(parallel, "runnable_others", lambda: None)  # a system without a count of runnable threads
    monkeypatch.setattr(parallel, "_OWN_WORK", parallel.deque())  # no bind of this process before
    monkeypatch.setattr(parallel.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(parallel.os, "getloadavg", lambda: (0.3, 0.0, 0.0))  # a bind keeps 1.3 cores busy
    assert parallel.busy_factor() == 1.0
    monkeypatch.setattr(parallel.os, "getloadavg", lambda: (2.0, 0.0, 0.0))  # two other busy threads
    assert parallel.busy_factor() == pytest.approx(1.65)
    monkeypatch.setattr(parallel.os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert parallel.busy_factor() == 1.0

    def unavailable():
        raise OSError("no load average here")

    monkeypatch.setattr(parallel.os, "getloadavg", unavailable)
    assert parallel.busy_factor() == 1.0


def test_the_busy_factor_leaves_out_the_load_this_process_s_own_finished_binds_left(monkeypatch):
    """A new user's finding: right after a long bind, the next one's forecast said the machine was busy."""
    monkeypatch.setattr(parallel, "runnable_others", lambda: None)
    monkeypatch.setattr(parallel.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(parallel.os, "getloadavg", lambda: (2.7, 0.0, 0.0))
    monkeypatch.setattr(parallel, "_OWN_WORK", parallel.deque())
    assert parallel.busy_factor() == pytest.approx(2.0)
    now = parallel.time.monotonic()
    parallel._OWN_WORK.append((now, 60.0, 120.0))  # a one-minute bind on two threads, just ended
    assert parallel.own_load(now) == pytest.approx(2 * (1 - np.exp(-1)))  # 1.26 of the load is its own
    assert parallel.busy_factor() == pytest.approx((2.7 - 2 * (1 - np.exp(-1)) + 1.3) / 2, abs=1e-3)
    assert parallel.own_load(now + 60) == pytest.approx(2 * (1 - np.exp(-1)) * np.exp(-1))  # decayed a minute on


def test_a_counted_function_records_its_work_once_however_nested(monkeypatch):
    monkeypatch.setattr(parallel, "_OWN_WORK", parallel.deque())

    @parallel.counted_in_load
    def inner():
        end = parallel.time.process_time() + 0.05
        while parallel.time.process_time() < end:
            pass

    @parallel.counted_in_load
    def outer():
        inner()

    outer()
    inner()
    assert len(parallel._OWN_WORK) == 2
    assert all(cpu >= 0.05 for _, _, cpu in parallel._OWN_WORK)


def test_the_busy_factor_counts_the_threads_runnable_now_where_the_system_says(monkeypatch, tmp_path):
    """New users' findings: binds run one after another from the command line were told the machine was 2.3-3.1
    times busier than it was (the load average still counted the binds that had just ended); then, counting the
    threads runnable now, an idle machine was told busy (this process's own BLAS threads, spinning after a product,
    were counted as other jobs)."""
    loadavg, tasks = tmp_path / "loadavg", tmp_path / "task"
    for thread, state in ((101, "R"), (102, "R"), (103, "S")):  # the reader and a spinning BLAS thread run
        (tasks / str(thread)).mkdir(parents=True)
        (tasks / str(thread) / "stat").write_text(f"{thread} (python (main)) {state} 1 2 3 4\n")
    monkeypatch.setattr(parallel.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(parallel.os, "getloadavg", lambda: (3.0, 0.0, 0.0))  # a minute's busy past
    read = parallel.runnable_others
    monkeypatch.setattr(parallel, "runnable_others", lambda: read(str(loadavg), str(tasks), spacing=0.0))
    loadavg.write_text("3.00 1.00 0.50 2/312 4242\n")  # only this process's two runnable threads
    assert parallel.busy_factor() == 1.0
    loadavg.write_text("3.00 1.00 0.50 4/312 4242\n")  # and two threads of another job
    assert parallel.busy_factor() == pytest.approx(1.65)
    assert read(str(tmp_path / "missing"), str(tasks)) is None  # no such count here: the load average's turn


def test_runnable_threads_are_averaged_over_a_few_readings(tmp_path, monkeypatch):
    readings = iter(["0.1 0.1 0.1 %d/9 1\n" % count for count in (1, 3, 1, 3)])
    monkeypatch.setattr(parallel.time, "sleep", lambda seconds: None)
    monkeypatch.setattr(parallel, "_running_threads", lambda tasks: 1)
    monkeypatch.setattr("builtins.open", lambda path: __import__("io").StringIO(next(readings)))
    assert parallel.runnable_others("/proc/loadavg", samples=4) == 1.0


def test_this_process_s_running_threads_are_counted_from_their_states():
    assert parallel._running_threads("/proc/self/task") >= 1  # the caller itself runs
