"""Live campaigns against a plant, driven by APScheduler on the plant clock.

Three jobs run in a background scheduler (UTC, module-level callables, fixed ids):

* ``helicalib-weather``: weather poll every :data:`~helicalib.campaign.runner.WEATHER_POLL_S`
  plant seconds (stow within one poll);
* ``helicalib-tick``: the runner's tick (visits stepped when due, planner when a target is free),
  every :data:`TICK_PLANT_S` plant seconds;
* ``helicalib-daylight``: at the next sunrise/sunset through the low band's lower edge, an event
  that opens or closes the day (the tick also gates on the sun, so a missed job loses nothing).

Plant seconds become real seconds through the plant clock's rate (``plant.clock: plant`` reads
the plant's time and rate registers). The main thread waits until ``until_s`` or Ctrl-C, then
stops the jobs and hands every heliostat still in a visit back to tracking.
"""

from __future__ import annotations

import datetime as dt
import signal
import threading

from helicalib.campaign.runner import WEATHER_POLL_S, CampaignRunner
from helicalib.errors import HelicalibError

TICK_PLANT_S = 2.0
"""Plant seconds between ticks (the visit loop's status-poll granularity)."""
MIN_REAL_INTERVAL_S = 0.05


def _rate(clock) -> float:
    rate = getattr(clock, "rate", None)
    if callable(rate):
        rate = rate()
    return float(rate) if rate else 1.0


def _tick_job(runner: CampaignRunner, lock: threading.Lock) -> None:
    if not lock.acquire(blocking=False):
        return
    try:
        runner.tick(runner.clock.now_s())
    except HelicalibError as err:  # a job must never die: record and go on
        runner.store.record_event(campaign_id=runner.campaign_id, time_s=runner.clock.now_s(), kind="fault",
                                  reason=f"tick: {err}")
    finally:
        lock.release()


def _weather_job(runner: CampaignRunner, lock: threading.Lock) -> None:
    with lock:
        runner._poll_weather(runner.clock.now_s())


def _daylight_job(runner: CampaignRunner, scheduler, lock: threading.Lock) -> None:
    with lock:
        now = runner.clock.now_s()
        _vec, _az, el, rising = runner.sun(now)
        kind = "note"
        runner.store.record_event(campaign_id=runner.campaign_id, time_s=now, kind=kind,
                                  reason=f"sun at {el:.1f}° ({'rising' if rising else 'setting'}): day "
                                         f"{'opens' if rising else 'closes'}")
    schedule_daylight(runner, scheduler, lock)


def schedule_daylight(runner: CampaignRunner, scheduler, lock) -> None:
    """Schedule the next crossing of the low band's lower edge (either way)."""
    now = runner.clock.now_s()
    level = runner.cfg.acceptance.low_band_deg[0]
    above = runner.sun(now)[2] >= level
    t = now
    for _ in range(2 * 24 * 12):
        t += 300.0
        if (runner.sun(t)[2] >= level) != above:
            break
    real_s = max(0.0, (t - now) / _rate(runner.clock))
    when = dt.datetime.now(dt.timezone.utc) + dt.timedelta(seconds=real_s)
    scheduler.add_job(_daylight_job, "date", run_date=when, args=[runner, scheduler, lock],
                      id="helicalib-daylight", replace_existing=True, misfire_grace_time=None)


def run_live(runner: CampaignRunner, until_s: float, stop_event: threading.Event | None = None, done=None) -> None:
    """Run ``runner`` on APScheduler until plant time ``until_s``, ``done()`` is true, or SIGINT/SIGTERM/``stop_event``."""
    import logging

    from apscheduler.schedulers.background import BackgroundScheduler

    # a tick still running when the next is due is skipped by design (max_instances=1): not news
    logging.getLogger("apscheduler").setLevel(logging.ERROR)
    stop = stop_event or threading.Event()
    lock = threading.Lock()
    rate = _rate(runner.clock)
    scheduler = BackgroundScheduler(timezone=dt.timezone.utc)
    common = dict(replace_existing=True, coalesce=True, max_instances=1, misfire_grace_time=None)
    scheduler.add_job(_weather_job, "interval", seconds=max(MIN_REAL_INTERVAL_S, WEATHER_POLL_S / rate),
                      args=[runner, lock], id="helicalib-weather", next_run_time=dt.datetime.now(dt.timezone.utc),
                      **common)
    scheduler.add_job(_tick_job, "interval", seconds=max(MIN_REAL_INTERVAL_S, TICK_PLANT_S / rate),
                      args=[runner, lock], id="helicalib-tick", **common)
    schedule_daylight(runner, scheduler, lock)
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    scheduler.start()
    last = {"now": None}

    def plant_now() -> float | None:
        """Plant time, or None while the plant does not answer (the jobs retry; nothing stops)."""
        try:
            last["now"] = runner.clock.now_s()
        except HelicalibError:
            return None
        return last["now"]

    try:
        while not stop.is_set() and not (done is not None and done()):
            now = plant_now()
            if now is not None and now >= until_s:
                break
            stop.wait(min(1.0, max(0.05, 5.0 / rate)))
    finally:
        scheduler.shutdown(wait=True)
        with lock:
            now = plant_now()
            runner.shutdown(now if now is not None else (last["now"] or until_s))
        for sig, handler in previous.items():
            signal.signal(sig, handler)
