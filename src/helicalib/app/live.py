"""Live campaigns against a plant, driven by APScheduler on the plant clock.

Three jobs run in a background scheduler (UTC, module-level callables, fixed ids):

* ``helicalib-weather``: weather poll every :data:`~helicalib.campaign.field.WEATHER_POLL_S`
  plant seconds (stow within one poll). It never waits behind a tick held up by a slow device: when
  the tick keeps the lock beyond :data:`WEATHER_WAIT_S`, it reads the weather and stows the field
  on its own (the visits' commands are then refused, and the tick ends the visits when it is back);
* ``helicalib-tick``: the runner's tick (visits stepped when due, planner when a target is free),
  every :data:`TICK_PLANT_S` plant seconds, and at once when a frame a visit waits for is in; each
  camera's frames, and a reading's spot, are taken on a thread of their own
  (:mod:`helicalib.campaign.frames`), so a visit waiting for its frames never holds the other boards';
* ``helicalib-daylight``: at the next sunrise/sunset through the low band's lower edge, an event
  that opens or closes the day (the tick also gates on the sun, so a missed job loses nothing).

Plant seconds become real seconds through the plant clock's rate (``plant.clock: plant`` reads
the plant's time and rate registers). The main thread waits until ``until_s`` or Ctrl-C, then
stops the jobs and hands every heliostat still in a visit back to tracking. A run also stops by
itself, the field made safe the same way, when the plant's clock jumps (backwards, or forwards
beyond where it can be)
(``reason="clock_jump"``) or the database cannot be written
(:data:`~helicalib.campaign.journal.STORAGE_RETRIES` writes in a row, ``reason="storage"``).
"""

from __future__ import annotations

import datetime as dt
import signal
import sys
import threading
import traceback
from dataclasses import dataclass, field

from helicalib.campaign.field import WEATHER_POLL_S
from helicalib.campaign.loop import CampaignRunner
from helicalib.campaign.sensor import frames_off_thread
from helicalib.devices.clock import ClockJumpError
from helicalib.devices.modbus_link import quiet_pymodbus
from helicalib.devices.protocols import Clock, PlantUnreachableError
from helicalib.errors import HelicalibError

TICK_PLANT_S = 2.0
"""Plant seconds between ticks (the visit loop's status-poll granularity)."""
FRAME_PASSES = 3
"""Times a live tick steps again the visits whose frames are on their way (:meth:`CampaignRunner.tick`)."""
MIN_REAL_INTERVAL_S = 0.05
WEATHER_WAIT_S = 0.5
"""Real seconds the weather job waits for a tick in progress before it reads the weather and stows
without it (a tick may wait up to a camera's fetch deadline on a slow device)."""


def _rate(clock: Clock) -> float:
    """Plant seconds per real second of ``clock`` (a clock that reports 0 counts as real time)."""
    return float(clock.rate) or 1.0


def _guarded(runner: CampaignRunner, what: str, fn) -> None:
    """Run one job step; any failure becomes ONE fault event (never a traceback per retry).

    A :class:`HelicalibError` is the plant or a device saying no: its line is the whole story. Any
    other exception is a bug: its line names the type, and its traceback goes once to
    ``<database>.errors.log`` beside the database.
    """
    try:
        fn()
    except ClockJumpError as err:  # one line; the run stops (run_live)
        runner.journal.clock_jumped(err)
    except Exception as err:  # noqa: BLE001 - a job must never die, nor print a traceback each retry
        if runner.journal.storage_fault(err):  # a full disk, a read-only database: counted (the run stops after a few)
            return
        if isinstance(err, HelicalibError):
            _said(runner, what, err)
            return
        log = runner.devices.store.path.with_name(runner.devices.store.path.name + ".errors.log")
        try:
            with open(log, "a", encoding="utf-8") as fh:
                fh.write(f"--- {dt.datetime.now(dt.timezone.utc).isoformat()} {what}\n{traceback.format_exc()}\n")
        except OSError:
            pass
        _fault(runner, f"{what}: internal error {type(err).__name__}: {err} (traceback in {log})")
    else:  # the job's next refusal is news again
        if runner.state.faults.job_fault:
            runner.state.faults.job_fault.pop(what, None)


def _said(runner: CampaignRunner, what: str, err: HelicalibError) -> None:
    """The plant or a device said no: a plant that does not answer is one line per job and loss; a
    refusal one line while its reason stays."""
    if isinstance(err, PlantUnreachableError):
        runner.journal.plant_failed(f"{what}: {err}")
        if not runner.journal.said_once(what):
            _fault(runner, f"{what}: {err}")
    else:
        _recorded(lambda: runner.journal.job_failed(what, f"{what}: {err}"), f"{what}: {err}")


def _fault(runner: CampaignRunner, reason: str) -> None:
    _recorded(lambda: runner.event("fault", reason), reason)


def _recorded(record, reason: str) -> None:
    """``record()`` the fault line ``reason``, or print it on stderr if even that fails."""
    try:
        record()
    except Exception:  # noqa: BLE001 - even the store may be gone (full disk): say it on stderr, once a line
        _quietly(lambda: print(f"helicalib: fault (not recorded): {reason}", file=sys.stderr, flush=True))


KICKED_TICKS = 4
"""Ticks a tick job runs back to back while frames keep coming in during them (then it asks the
scheduler for the next at once): the scheduler counts a job as running until it returns, so a run
asked from within it could be skipped as a second instance."""


def _tick_job(runner: CampaignRunner, lock: threading.Lock, kick: _Kick | None = None) -> None:
    if not lock.acquire(blocking=False):
        return
    try:
        for _ in range(KICKED_TICKS):
            if kick is not None:
                kick.asked.clear()  # a frame in from now on is news for the next tick
            if runner.state.stopping:
                break
            _guarded(runner, "tick", lambda: runner.tick(runner.devices.clock.now_s()))
            if kick is None or not kick.asked.is_set():  # no frame came in during the tick
                break
    finally:
        lock.release()
    if kick is not None and kick.asked.is_set():  # still frames coming in: the next job at once
        kick()


class _Kick:
    """The tick run at once, not at its next period, when a frame a visit waits for is in (the
    cameras' :attr:`~helicalib.campaign.frames.FrameWorker.on_done`): at 10× a tick's period is two
    plant seconds the plant would wait. One asked while a tick runs (and may have missed it) runs the
    next tick straight after it (:func:`_tick_job`)."""

    def __init__(self, scheduler, runner: CampaignRunner):
        self.scheduler, self.runner = scheduler, runner
        self.asked = threading.Event()

    def __call__(self) -> None:
        self.asked.set()
        if self.runner.state.stopping:
            return
        try:
            self.scheduler.modify_job("helicalib-tick", next_run_time=dt.datetime.now(dt.timezone.utc))
        except Exception:  # noqa: BLE001 - the scheduler stopping: the run's end takes over
            pass


def _weather_job(runner: CampaignRunner, lock: threading.Lock) -> None:
    if runner.state.stopping:
        return
    if lock.acquire(timeout=WEATHER_WAIT_S):
        try:
            if not runner.state.stopping:
                _guarded(runner, "weather", lambda: runner.field.poll_weather(runner.devices.clock.now_s()))
        finally:
            lock.release()
    else:  # a tick waits on a slow device: read the weather and stow without it
        _guarded(runner, "weather", lambda: runner.field.poll_weather(runner.devices.clock.now_s(), preempt=True))


def _daylight_job(runner: CampaignRunner, scheduler, lock: threading.Lock) -> None:
    def job():
        now = runner.devices.clock.now_s()
        _vec, _az, el, rising = runner.sun(now)
        runner.event("note", f"sun at {el:.1f}° ({'rising' if rising else 'setting'}): day "
                             f"{'opens' if rising else 'closes'}", time_s=now)

    with lock:
        if runner.state.stopping:
            return
        _guarded(runner, "daylight", job)
    _guarded(runner, "daylight", lambda: schedule_daylight(runner, scheduler, lock))


def schedule_daylight(runner: CampaignRunner, scheduler, lock) -> None:
    """Schedule the next crossing of the low band's lower edge (either way)."""
    now = runner.devices.clock.now_s()
    level = runner.cfg.acceptance.low_band_deg[0]
    above = runner.sun(now)[2] >= level
    t = now
    for _ in range(2 * 24 * 12):
        t += 300.0
        if (runner.sun(t)[2] >= level) != above:
            break
    real_s = max(0.0, (t - now) / _rate(runner.devices.clock))
    when = dt.datetime.now(dt.timezone.utc) + dt.timedelta(seconds=real_s)
    scheduler.add_job(_daylight_job, "date", run_date=when, args=[runner, scheduler, lock],
                      id="helicalib-daylight", replace_existing=True, misfire_grace_time=None)


@dataclass
class LiveResult:
    """How a live run ended: ``reason`` ("until", "done", "stopped", "clock_jump", "storage");
    heliostats left off tracking."""

    reason: str
    off_tracking: list[str] = field(default_factory=list)


def run_live(runner: CampaignRunner, until_s: float, stop_event: threading.Event | None = None, done=None,
             output=None) -> LiveResult:
    """Run ``runner`` on APScheduler until plant time ``until_s``, ``done()`` is true, or SIGINT/SIGTERM/``stop_event``.

    ``output`` (see :mod:`.terminal`) gets every event and, twice a second, a snapshot. A first
    Ctrl-C stops cleanly: the step in progress ends (plant requests become single attempts), the
    beams on the boards leave via standby and every return to tracking is checked; a second Ctrl-C
    leaves at once.
    """
    import logging

    from apscheduler.schedulers.background import BackgroundScheduler

    # a tick still running when the next is due is skipped by design (max_instances=1): not news;
    # a lost plant is one fault line of ours, not pymodbus's own log lines
    logging.getLogger("apscheduler").setLevel(logging.CRITICAL)
    quiet_pymodbus()
    stop = stop_event or threading.Event()
    lock = threading.Lock()
    hurries = runner.devices.abilities.hurries  # a stop asks such a plant to drop its retries
    if output is not None and output.on_event not in runner.journal.listeners:
        runner.journal.listeners.append(output.on_event)
    rate = _rate(runner.devices.clock)
    previous = {}
    signals = {"n": 0}

    def on_signal(*_):
        signals["n"] += 1
        stop.set()
        if signals["n"] > 1:
            raise KeyboardInterrupt

    stop_frames = None
    try:  # the jobs' start: should it fail, the frame workers and the signal handlers are given back
        scheduler = BackgroundScheduler(timezone=dt.timezone.utc)
        kick = _Kick(scheduler, runner)
        # a board's frames and their vision never hold the other boards' visits; one in asks for a tick
        stop_frames = frames_off_thread(runner.devices.sensors, on_done=kick)
        runner.field.spread_cleanliness = True  # nor does a choice's reading of its candidates' cleanliness
        runner.tracking.batches = runner.devices.abilities.parallel_tracking  # nor the tracking refresh
        runner.frame_passes = FRAME_PASSES  # a frame that came in during the tick is used in that tick
        common = dict(replace_existing=True, coalesce=True, max_instances=1, misfire_grace_time=None)
        scheduler.add_job(_weather_job, "interval", seconds=max(MIN_REAL_INTERVAL_S, WEATHER_POLL_S / rate),
                          args=[runner, lock], id="helicalib-weather",
                          next_run_time=dt.datetime.now(dt.timezone.utc), **common)
        scheduler.add_job(_tick_job, "interval", seconds=max(MIN_REAL_INTERVAL_S, TICK_PLANT_S / rate),
                          args=[runner, lock, kick], id="helicalib-tick", **common)
        if threading.current_thread() is threading.main_thread():  # before anything slow: a Ctrl-C now stops cleanly
            for sig in (signal.SIGINT, signal.SIGTERM):
                previous[sig] = signal.signal(sig, on_signal)
        _guarded(runner, "daylight", lambda: schedule_daylight(runner, scheduler, lock))
        scheduler.start()
    except BaseException:
        if stop_frames is not None:
            stop_frames()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        raise
    result = LiveResult("stopped")

    def plant_now() -> float | None:
        """Plant time, or None while the plant does not answer (the jobs retry; nothing stops)."""
        try:
            return runner.devices.clock.now_s()
        except HelicalibError:
            return None

    def show() -> None:
        if output is None:
            return
        held = lock.acquire(timeout=0.2)  # not held: a tick waits on a slow device; the view goes on
        try:  # the controller's own clock: a view must not wait on a plant that does not answer
            output.on_snapshot(runner.snapshot(runner.devices.clock.estimate_s()))
        except Exception:  # noqa: BLE001 - a view must never stop the campaign (nor a read racing a tick)
            pass
        finally:
            if held:
                lock.release()

    try:
        if output is not None:
            _quietly(output.start)
        while not stop.is_set():
            if done is not None and done():
                result.reason = "done"
                break
            if runner.state.faults.clock_jump is not None or runner.state.faults.storage_lost is not None:
                result.reason = "clock_jump" if runner.state.faults.clock_jump is not None else "storage"
                break
            now = plant_now()
            if now is not None and now >= until_s:
                result.reason = "until"
                break
            show()
            stop.wait(min(0.5, max(0.05, 5.0 / rate)))
    finally:
        # the stop runs whatever ended the loop (the end time, Ctrl-C, a view that raised, a closed pipe)
        try:
            if result.reason in ("stopped", "clock_jump", "storage"):
                why = {"stopped": "", "clock_jump": " (the plant's clock jumped)",
                       "storage": " (the database cannot be written)"}[result.reason]
                _say(output, f"stopping{why}: finishing the step in progress, then every beam on a board leaves via "
                             "its standby point and goes back to tracking (Ctrl-C again to leave at once)")
                if hurries:
                    runner.devices.plant.hurry()
            scheduler.shutdown(wait=False)
            waited = 0
            while not lock.acquire(timeout=1.0):
                waited += 1
                if waited % 5 == 0:
                    _say(output, f"stopping: still waiting for the step in progress ({waited} s; a plant or camera "
                                 "request)")
            try:
                runner.state.stopping = True  # jobs still queued behind the lock do nothing more
                if runner.state.active:
                    _say(output, f"stopping: {len(runner.state.active)} heliostat(s) leaving their boards via standby")
                result.off_tracking = runner.shutdown(runner.journal.safe_now()[0])
            finally:
                lock.release()
            show()
        finally:
            stop_frames()
            runner.field.close()
            if output is not None:
                _quietly(output.stop)
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            if output is not None and output.on_event in runner.journal.listeners:
                runner.journal.listeners.remove(output.on_event)
    return result


def _quietly(fn) -> None:
    try:
        fn()
    except Exception:  # noqa: BLE001 - what the crew sees must never stop the campaign or its stop
        pass


def _say(output, text: str) -> None:
    if output is not None:
        _quietly(lambda: output.message(text))
