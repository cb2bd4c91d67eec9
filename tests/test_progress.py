"""Progress: reports mapped onto sub-ranges, cancellation raised at reports and checks."""

import pytest

from lbc_core.errors import Cancelled
from lbc_core.kernel.progress import Progress


def test_parts_map_onto_the_parent_range():
    seen = []
    whole = Progress(lambda fraction, message: seen.append((round(fraction, 9), message)))
    solve = whole.part(0.2, 0.6)
    solve(0.5, "half")
    solve.part(0.5, 1.0)(1.0, "end")
    assert seen == [(0.4, "half"), (0.6, "end")]


def test_cancel_raises_at_reports_and_checks():
    flag = [False]
    progress = Progress(None, lambda: flag[0]).part(0.1, 0.2)
    progress(0.3, "fine")
    progress.check()
    flag[0] = True
    with pytest.raises(Cancelled):
        progress.check()
    with pytest.raises(Cancelled):
        progress(0.5, "too late")


def test_of_keeps_a_progress_and_wraps_callbacks():
    existing = Progress()
    assert Progress.of(existing) is existing
    seen = []
    Progress.of(lambda f, m: seen.append(f), None)(1.0, "done")
    assert seen == [1.0]


def test_of_a_progress_with_a_cancel_beside_it_polls_both():
    """A code review's finding: the cancel given beside a Progress was dropped."""
    told = []
    outer = Progress(lambda fraction, message: told.append(fraction)).part(0.5, 1.0)
    stop = []
    both = Progress.of(outer, lambda: bool(stop))
    both(0.5, "half")
    assert told == [0.75]
    stop.append(1)
    with pytest.raises(Cancelled):
        both.check()
    with pytest.raises(Cancelled):
        Progress.of(Progress(None, lambda: True), lambda: False).check()  # the Progress's own cancel still counts


def test_a_part_may_begin_its_messages_with_a_prefix():
    """The mesher's second try said "sampling the cage surface" again with the bar stepping back: a new user read it
    as a restart. Its part now says what it is."""
    told = []
    progress = Progress(lambda fraction, message: told.append((fraction, message)))
    progress.part(0.5, 1.0, "meshing again: ")(0.5, "sampling the cage surface")
    progress.part(0.0, 0.5)(1.0, "plain")
    assert told == [(0.75, "meshing again: sampling the cage surface"), (0.5, "plain")]
    Progress().part(0.0, 1.0, "nobody listens: ")(0.5, "fine")  # no callback: nothing to prefix
