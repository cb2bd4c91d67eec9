"""Progress reporting and cancellation: the one mechanism every long stage uses.

A stage receives a :class:`Progress`, calls it with its own fraction done (0 to 1) between steps, and calls
:meth:`Progress.check` inside any loop that could run long; both raise :class:`~lbc_core.errors.Cancelled` as soon as
the user's ``cancel()`` returns True. :meth:`Progress.part` hands a sub-stage its own 0-to-1 range.
"""

import time

from ..errors import Cancelled


class Laps:
    """Seconds per stage of a run: each :meth:`lap` gives the time since the previous one to its stage (summed when a
    stage comes back). The one timing idiom of the pipeline and the solvers.

    Example
    -------
    >>> laps = Laps()
    >>> laps.lap("meshing")
    >>> sorted(laps.seconds)
    ['meshing']
    """

    def __init__(self):
        self.seconds = {}
        self._last = time.perf_counter()

    def lap(self, stage):
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._last
        self._last = now

    def restart(self):
        """The next lap counts from now (the time since the last one belongs to no stage)."""
        self._last = time.perf_counter()


class Progress:
    """The user's ``progress(fraction, message)`` and ``cancel() -> bool`` callbacks, mapped onto a range.

    Parameters
    ----------
    progress : callable(fraction, message) or None
        Told the overall fraction done (0 to 1) and what is being done.
    cancel : callable() -> bool or None
        Polled at every report and check; when it returns True, :class:`Cancelled` is raised.
    start, end : float
        The part of the user's 0-to-1 range this object's own 0-to-1 range maps onto.
    """

    def __init__(self, progress=None, cancel=None, start=0.0, end=1.0):
        self._progress = progress
        self._cancel = cancel
        self.start = float(start)
        self.end = float(end)

    @classmethod
    def of(cls, progress=None, cancel=None):
        """``progress`` when it already is a Progress (a ``cancel`` given beside it is polled too), else a new one
        over the two callbacks."""
        if isinstance(progress, Progress):
            if cancel is None:
                return progress
            inner = progress._cancel
            return cls(progress._progress, cancel if inner is None else lambda: inner() or cancel(), progress.start,
                       progress.end)
        return cls(progress, cancel)

    def check(self):
        """Raise :class:`Cancelled` when ``cancel()`` returns True; cheap enough for the inside of long loops."""
        if self._cancel is not None and self._cancel():
            raise Cancelled("cancelled")

    def __call__(self, fraction, message):
        """Check for cancellation, then report ``fraction`` (0 to 1) of this range done, with ``message``."""
        self.check()
        if self._progress is not None:
            self._progress(self.start + (self.end - self.start) * float(fraction), message)

    def part(self, start, end, prefix=""):
        """A Progress for the sub-range [start, end] (fractions of this one), sharing the same callbacks; its
        messages begin with ``prefix`` (e.g. "meshing again: ")."""
        span = self.end - self.start
        report = self._progress
        if prefix and report is not None:
            report = lambda fraction, message: self._progress(fraction, prefix + message)  # noqa: E731
        return Progress(report, self._cancel, self.start + span * start, self.start + span * end)
