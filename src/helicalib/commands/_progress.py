"""Progress of a long command on stderr, for a person at a terminal and for a log file alike.

On a terminal :class:`ProgressReporter` draws a rich progress bar. Anywhere else (``make`` piping
into a log, CI, ``2> file``) a bar would be switched off and the command would say nothing for
minutes, so it prints plain lines instead, at most one every ``interval_s`` of real time::

    simulate: day 0.42 of 2, 113 visits, 12 accepted, elapsed 31 s

The first update prints at once and :meth:`ProgressReporter.close` prints a closing line, so a log
shows when the work started, how it went and how long it took. :func:`timed_step` brackets one
step without a measure of its own (a report build) with a start line and an end line.

The clock and the interval are injected (tests run with a fake clock and no sleeping).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO

__all__ = ["DEFAULT_INTERVAL_S", "ProgressReporter", "format_elapsed", "timed_step"]

DEFAULT_INTERVAL_S = 10.0
"""Real seconds between two plain progress lines."""
BAR_TEXT_INTERVAL_S = 1.0
"""Real seconds between two evaluations of a callable description while the bar is drawn."""

Text = str | Callable[[], str]


def format_elapsed(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``1 h 02 min``."""
    s = int(round(max(0.0, seconds)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


class ProgressReporter:
    """A progress bar on a terminal, plain rate-limited lines elsewhere; use as a context manager.

    Parameters
    ----------
    label : str
        Command name at the start of every line (``simulate``).
    total : float or None
        Amount of work in the units of :meth:`update`'s ``completed`` (None: unknown).
    interval_s : float, optional
        Least real time between two plain lines [s]; default :data:`DEFAULT_INTERVAL_S` (read when
        the reporter is made).
    stream : file, optional
        Where to write (default ``sys.stderr``, looked up when the reporter is made).
    clock : callable
        Real time [s] (``time.monotonic``).
    terminal : bool, optional
        Force the bar (True) or the plain lines (False); default: whether ``stream`` is a terminal
        (rich's rules, so ``FORCE_TERMINAL``/``TTY_COMPATIBLE`` are honoured).
    transient : bool
        Remove the bar when done (terminal only).
    """

    def __init__(self, label: str, total: float | None = None, *, interval_s: float | None = None,
                 stream: TextIO | None = None, clock: Callable[[], float] = time.monotonic,
                 terminal: bool | None = None, transient: bool = False):
        from rich.console import Console

        self.label = label
        self.total = total
        self.interval_s = float(DEFAULT_INTERVAL_S if interval_s is None else interval_s)
        self.stream = sys.stderr if stream is None else stream
        self.clock = clock
        self.console = Console(file=self.stream, force_terminal=terminal)
        self.terminal = self.console.is_terminal if terminal is None else bool(terminal)
        self.transient = transient
        self.lines = 0
        self._t0 = clock()
        self._last_line: float | None = None
        self._last_text_t: float | None = None
        self._text = ""
        self._latest: Text = ""
        self._bar = None
        self._task = None

    # -- life cycle ---------------------------------------------------------------------------
    def __enter__(self) -> ProgressReporter:
        if self.terminal:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

            self._bar = Progress(TextColumn(f"[bold]{self.label}[/]"), BarColumn(), TextColumn("{task.description}", markup=False),
                                 TimeElapsedColumn(), TimeRemainingColumn(), console=self.console,
                                 transient=self.transient)
            self._bar.start()
            self._task = self._bar.add_task("", total=self.total)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(ok=exc_type is None)

    def close(self, ok: bool = True) -> None:
        """Stop the bar, or print the closing plain line (with the last description)."""
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
            return
        if self._last_line is None:
            return                                   # never shown: nothing to close (a failure says itself)
        state = "done" if ok else "stopped"
        latest = self._latest() if callable(self._latest) else self._latest
        text = f", {latest}" if latest else ""
        self._print(f"{self.label}: {state}{text}, elapsed {format_elapsed(self.clock() - self._t0)}")

    # -- reporting ----------------------------------------------------------------------------
    def update(self, completed: float, text: Text = "", total: float | None = None) -> None:
        """Work done so far; ``text`` describes it (a callable is only called when it is shown)."""
        now = self.clock()
        self._latest = text
        if total is not None:
            self.total = total
        if self._bar is not None:
            if self._last_text_t is None or now - self._last_text_t >= BAR_TEXT_INTERVAL_S:
                self._text = text() if callable(text) else text
                self._last_text_t = now
            self._bar.update(self._task, completed=completed, total=self.total, description=self._text)
            return
        if self._last_line is not None and now - self._last_line < self.interval_s:
            return
        self._text = text() if callable(text) else text
        self._last_line = now
        self._print(f"{self.label}: {self._text}, elapsed {format_elapsed(now - self._t0)}" if self._text
                    else f"{self.label}: elapsed {format_elapsed(now - self._t0)}")

    def note(self, message: str) -> None:
        """One line now, above the bar on a terminal."""
        if self._bar is not None:
            self._bar.console.print(message, markup=False, highlight=False)
        else:
            self._print(message)

    def _print(self, line: str) -> None:
        print(line, file=self.stream, flush=True)
        self.lines += 1


@contextmanager
def timed_step(label: str, what: str, *, stream: TextIO | None = None,
               clock: Callable[[], float] = time.monotonic) -> Iterator[None]:
    """``label: what ...`` before the step and ``label: what done in N s`` after it (or ``failed``)."""
    out = sys.stderr if stream is None else stream
    print(f"{label}: {what} ...", file=out, flush=True)
    t0 = clock()
    try:
        yield
    except BaseException:
        print(f"{label}: {what} failed after {format_elapsed(clock() - t0)}", file=out, flush=True)
        raise
    print(f"{label}: {what} done in {format_elapsed(clock() - t0)}", file=out, flush=True)


class TaskTally:
    """Tasks done of all, and how many failed, on a :class:`ProgressReporter` (Dask runs of
    ``sweep`` and split ``simulate``): :meth:`ended` once per task, a failure noted with its reason."""

    def __init__(self, bar: ProgressReporter, command: str, noun: str):
        self.bar, self.command, self.noun = bar, command, noun
        self.total = self.done = self.failed = 0

    def ended(self, reason: str | None) -> None:
        """One task ended (``reason``: why it failed, None when it did not)."""
        self.done += 1
        if reason is not None:
            self.failed += 1
            self.bar.note(f"{self.command}: failed: {reason}")
        failed = f", {self.failed} failed" if self.failed else ""
        self.bar.update(self.done, f"{self.done} of {self.total} {self.noun}{failed}")
