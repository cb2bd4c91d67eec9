"""What ``lbc`` prints: warnings on stderr, figures as JSON or as a table, and a progress bar that fits the terminal.
"""

import json
import shutil
import sys
import textwrap
import time

import numpy as np


def warn(warnings, quiet):
    if not quiet:
        for warning in warnings:
            print(f"lbc: warning: {warning}", file=sys.stderr)


def print_json(figures):
    print(json.dumps(figures, indent=2, default=_json_default))


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


# (key, header, format) of the printed tables
SUMMARY_COLUMNS = [
    ("scheme", "scheme", "{}"),
    ("influence_mean", "influence mean", "{:.2f}"),
    ("influence_max", "max", "{}"),
    ("P_tau", "P(1e-3/n)", "{:.3f}"),
    ("Q_4", "Q(4)", "{:.3f}"),
    ("Q_8", "Q(8)", "{:.3f}"),
    ("memory_bytes", "weights KB", "{:.1f}", 1e-3),
    ("deform_seconds", "deform µs", "{:.1f}", 1e6),
    ("time_total", "bind s", "{:.2f}"),
]


def table(rows, columns):
    """Rows of figures as an aligned text table (numbers right-aligned)."""
    cells = [[header for _, header, *_ in columns]]
    for row in rows:
        row = dict(row, time_total=sum(v for k, v in row.items() if k.startswith("time_") and k != "time_total"))
        line = []
        for key, _, form, *scale in columns:
            value = row.get(key)
            line.append("-" if value is None else form.format(value * scale[0] if scale else value))
        cells.append(line)
    widths = [max(len(line[k]) for line in cells) for k in range(len(columns))]
    text = []
    for number, line in enumerate(cells):
        parts = [c.ljust(w) if k == 0 else c.rjust(w) for k, (c, w) in enumerate(zip(line, widths))]
        text.append("  ".join(parts))
        if number == 0:
            text.append("  ".join("-" * w for w in widths))
    return "\n".join(text)


BAR = 20  # characters of the progress bar: the message keeps most of an 80-column terminal


class ProgressBar:
    """A progress bar on stderr for a terminal, a line per tenth of the work otherwise (logs); nothing when quiet.

    Used as a context manager; the instance is the ``progress(fraction, message)`` callback.
    """

    def __init__(self, label, quiet):
        self.label = label
        self.enabled = not quiet
        self.tty = sys.stderr.isatty()
        # One line as wide as the terminal: a wider one wraps, and every redraw then scrolls a new line.
        self.width = shutil.get_terminal_size().columns - 1
        self.last_draw = 0.0
        self.last_tenth = -1
        self.start = time.perf_counter()

    def __call__(self, fraction, message):
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty:
            if fraction == 0.0 and len(message) > self.width // 2:
                # The forecast (memory and time) is told at 0: whole, on lines of its own, not cut to the bar's room.
                sys.stderr.write("\r" + " " * self.width + "\r" + textwrap.fill(message, self.width) + "\n")
            if now - self.last_draw < 0.1 and fraction < 1.0:
                return
            filled = int(round(BAR * min(max(fraction, 0.0), 1.0)))
            bar = "#" * filled + "-" * (BAR - filled)
            line = f"\r{self.label} [{bar}] {fraction:4.0%} {message}"[:self.width + 1]
            sys.stderr.write(line.ljust(self.width + 1))
            sys.stderr.flush()
            self.last_draw = now
        elif int(10 * fraction) > self.last_tenth:
            self.last_tenth = int(10 * fraction)
            sys.stderr.write(f"{self.label}: {fraction:4.0%} {message}\n")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if not self.enabled:
            return False
        if exc[0] is not None:  # the error message is the one line to read: only clear a drawn bar
            if self.tty:
                sys.stderr.write("\r" + " " * self.width + "\r")
            return False
        seconds = time.perf_counter() - self.start
        done = f"{self.label}: done in {seconds:.1f} s"
        sys.stderr.write(("\r" + done.ljust(self.width) if self.tty else done) + "\n")
        return False
