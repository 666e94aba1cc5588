"""What the controller's process tells its console page: snapshots and events, thread-safe.

:class:`LiveFeed` is a view of the campaign like the terminal's (``on_event``, ``on_snapshot``):
the runner's listener and :func:`~helicalib.app.live.run_live`'s output call it from the
scheduler's and the main thread; the web server's thread reads :meth:`LiveFeed.latest`. Every
method only swaps a reference or bumps a counter under a lock held for microseconds, so the
control loop never waits on the page. :class:`Tee` hands one output's calls to the terminal view
and to the feed.
"""

from __future__ import annotations

import threading

from helicalib.campaign.events import RunEvent, Snapshot


class LiveFeed:
    """The newest :class:`Snapshot`, and a version that changes with every event."""

    def __init__(self):
        self._lock = threading.Lock()
        self._snapshot: Snapshot | None = None
        self._version = 0
        self.running = False

    def on_event(self, ev: RunEvent) -> None:
        with self._lock:
            self._version += 1

    def on_snapshot(self, s: Snapshot) -> None:
        with self._lock:
            self._snapshot = s

    def latest(self) -> tuple[Snapshot | None, int]:
        """(the newest snapshot or None, the event version)."""
        with self._lock:
            return self._snapshot, self._version

    def bump(self) -> None:
        """Something the page shows changed outside the events (an action was requested)."""
        with self._lock:
            self._version += 1


class Tee:
    """One ``run_live`` output that is the crew's view (terminal, lines, JSON) and the console.

    Events, snapshots, start and stop go to both; messages and JSON lines to the view only (the
    console reads the database). Whatever the console does never raises into the campaign."""

    def __init__(self, view, feed: LiveFeed, on_start=None, on_stop=None):
        self.view, self.feed = view, feed
        self._on_start, self._on_stop = on_start, on_stop

    def __getattr__(self, name):  # message, emit, ... of the view
        return getattr(self.view, name)

    def on_event(self, ev: RunEvent) -> None:
        try:
            self.feed.on_event(ev)
        finally:
            self.view.on_event(ev)

    def on_snapshot(self, s: Snapshot) -> None:
        try:
            self.feed.on_snapshot(s)
        finally:
            self.view.on_snapshot(s)

    def start(self) -> None:
        self.view.start()
        if self._on_start is not None:
            self._on_start()

    def stop(self) -> None:
        try:
            if self._on_stop is not None:
                self._on_stop()
        finally:
            self.view.stop()
