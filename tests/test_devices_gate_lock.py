"""The stow gate's lock (devices/guard.py, GateLock): heliostat commands share it, a field command
holds it alone and is never overtaken by commands asked after it, and a field command interrupted
while it waits leaves nothing behind that would block the commands after it."""

from __future__ import annotations

import threading
import time

import pytest

from helicalib.devices.guard import GateLock


def _started(target) -> threading.Thread:
    t = threading.Thread(target=target, daemon=True)
    t.start()
    return t


def test_a_field_command_waits_for_shared_holders_and_goes_before_later_ones():
    lock, order = GateLock(), []
    held, release = threading.Event(), threading.Event()

    def command(name, gate=None):
        with lock.shared():
            order.append(name)
            if gate is not None:
                held.set()
                gate.wait(5.0)

    first = _started(lambda: command("track 1", release))
    assert held.wait(5.0)

    def stow():
        with lock:
            order.append("stow")

    field = _started(stow)
    while not lock._queue:          # the stow is queued behind the command in flight
        time.sleep(0.01)
    later = _started(lambda: command("track 2"))
    time.sleep(0.1)
    assert order == ["track 1"]     # neither the stow nor the later command got through
    release.set()
    for t in (first, field, later):
        t.join(5.0)
    assert order == ["track 1", "stow", "track 2"]


def test_a_field_command_interrupted_while_waiting_leaves_the_queue():
    lock = GateLock()
    held, release = threading.Event(), threading.Event()

    def command():
        with lock.shared():
            held.set()
            release.wait(5.0)

    first = _started(command)
    assert held.wait(5.0)

    def interrupted(timeout=None):
        raise KeyboardInterrupt

    lock._cond.wait = interrupted
    with pytest.raises(KeyboardInterrupt):
        with lock:
            pass
    assert not lock._queue and not lock._alone
    release.set()
    first.join(5.0)
    del lock._cond.wait
    done = threading.Event()
    _started(lambda: (lock.shared().__enter__(), done.set()))
    assert done.wait(5.0)           # a command after it is not blocked by a ticket left behind
