"""The stages of a bind as its progress messages tell them, and two instruments on its cancel polls: how often each
stage polls (tests/test_pipeline.py) and the longest wait between two polls in each (bench/cancel_latency.py)."""

import time

import lbc_core

# Each stage of a bind, told by the first progress message it sends (a prefix, or a tuple of them). A cancel must stop
# the stage it comes in (how long that takes is measured by bench/cancel_latency.py).
STAGE_MESSAGES = {
    "meshing": "",  # the first message of a bind is the mesher's
    "geodesics": "geodesic distances",
    # The working sets' start, or the dense splitting's factorisation where the solve takes it (small cages).
    "factorisation": ("finding where each control point may act", "factorising the solver's matrix"),
    "ADMM": "ADMM iteration",
    "projection": "projecting onto the constraints",
    "interpolation": "interpolation:",
    "reduction": "reducing the weights",
}


def stage_of(message, current):
    """The stage ``message`` announces, else ``current``."""
    return next((name for name, prefix in STAGE_MESSAGES.items() if prefix and message.startswith(prefix)), current)


def polls_by_stage(cage_vertices, cage_faces, points, **options):
    """How often each stage of a whole bind polls ``cancel``: a poll is the stage's whose message came last before
    it."""
    polls, stage = {}, ["meshing"]

    def progress(fraction, message):
        stage[0] = stage_of(message, stage[0])

    def cancel():
        polls[stage[0]] = polls.get(stage[0], 0) + 1
        return False

    lbc_core.bind(cage_vertices, cage_faces, points, progress=progress, cancel=cancel, **options)
    return polls


def longest_waits(cage_vertices, cage_faces, points, **options):
    """The longest time in seconds between two polls of ``cancel`` in each stage of a whole bind: the latency of a
    cancel that turns true at the worst moment. A wait is the stage's whose message came last before it began."""
    events = []  # (time, stage, or "poll")

    def progress(fraction, message):
        events.append((time.perf_counter(), stage_of(message, None)))

    def cancel():
        events.append((time.perf_counter(), "poll"))
        return False

    start = time.perf_counter()
    lbc_core.bind(cage_vertices, cage_faces, points, progress=progress, cancel=cancel, **options)
    longest, stage, last_poll = {}, "meshing", start
    for moment, kind in events:
        if kind == "poll":
            longest[stage] = max(longest.get(stage, 0.0), moment - last_poll)
            last_poll = moment
        elif kind is not None:
            stage = kind
    return longest
