"""Run a sweep's runs on Dask distributed and gather them.

:func:`embedded_cluster` starts a ``LocalCluster`` on 127.0.0.1 (worker processes with one thread
each: a simulation holds the GIL most of the time, so threads would take turns); :func:`connect`
joins an existing scheduler. :func:`run_sweep` skips finished runs, submits the others (one task
= one whole simulation) and hands each outcome to a callback as it arrives, in completion order;
nothing a run computes depends on that order.
"""

from __future__ import annotations

import logging
import traceback
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from helicalib.errors import ConfigError
from helicalib.sweep.spec import PROGRESS_EVERY, Run, Sweep
from helicalib.sweep.task import RunFailed, finished_record, has_result, run_one


@dataclass
class Outcome:
    """What became of each run of one sweep invocation."""

    records: dict[str, dict] = field(default_factory=dict)      # run_dir → record (finished now or before)
    failures: dict[str, tuple[str, str]] = field(default_factory=dict)  # run_dir → (one-line reason, traceback)
    skipped: int = 0        # finished before with the same settings
    stale: int = 0          # finished before with other settings: run again
    submitted: int = 0


@contextmanager
def embedded_cluster(workers: int) -> Iterator:
    """A client of a fresh ``LocalCluster`` of ``workers`` processes on 127.0.0.1, no dashboard; the
    cluster's own log is kept to critical messages (failed runs are reported by the sweep)."""
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.CRITICAL) as cluster, Client(cluster) as client:
        yield client


@contextmanager
def connect(address: str, timeout_s: float = 20.0) -> Iterator:
    """A client of the scheduler at ``address`` whose workers can import helicalib."""
    from dask.distributed import Client

    try:
        client = Client(address, timeout=timeout_s)
    except (OSError, TimeoutError, ValueError) as err:
        raise ConfigError(f"--scheduler {address}: cannot connect ({_one_line(err)})") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except TimeoutError:
            raise ConfigError(f"--scheduler {address}: no worker joined within {timeout_s:g} s") from None
        try:
            versions = client.run(_worker_check)
        except Exception as err:  # noqa: BLE001 - whatever a worker raised, said in one line
            raise ConfigError(f"--scheduler {address}: a worker cannot run helicalib ({type(err).__name__}: "
                              f"{_one_line(err)}); install helicalib in the workers' environment") from None
        check_workers(address, versions, client.nthreads())
        yield client
    finally:
        client.close()


def check_workers(address: str, versions: dict, nthreads: dict) -> None:
    """Refuse workers that run another helicalib (their results would be taken for this version's)
    or more than one thread (a simulation redirects its process's output to its own log)."""
    from helicalib import __version__

    other = sorted(w for w, v in versions.items() if v != __version__)
    if other:
        raise ConfigError(f"--scheduler {address}: worker {other[0]} runs helicalib {versions[other[0]]}, this is "
                          f"{__version__}; install the same version on every worker")
    many = sorted(w for w, n in nthreads.items() if n != 1)
    if many:
        raise ConfigError(f"--scheduler {address}: worker {many[0]} has {nthreads[many[0]]} threads; start the "
                          "workers with --nthreads 1 (one simulation per worker process, docs/sweep.md)")


def _worker_check() -> str:
    import helicalib.sweep.task  # noqa: F401 - the module the tasks run

    from helicalib import __version__

    return __version__


def run_sweep(sweep: Sweep, runs: list[Run], client, on_start: Callable[[int], None] | None = None,
              on_result: Callable[[Run, dict | None, str | None], None] | None = None,
              on_check: Callable[[int, int], None] | None = None) -> Outcome:
    """Skip finished runs, submit the others, gather them. ``on_check(done, total)`` every
    :data:`~helicalib.sweep.spec.PROGRESS_EVERY` runs while looking for finished ones;
    ``on_start(n_submitted)`` before the first result; ``on_result(run, record, reason)`` per run
    (``record`` None and a one-line ``reason`` when it failed)."""
    from dask.distributed import as_completed

    outcome = Outcome()
    todo = []
    for k, run in enumerate(runs, 1):
        if on_check is not None and k % PROGRESS_EVERY == 0:
            on_check(k, len(runs))
        record = finished_record(run)
        if record is not None:
            outcome.records[run.run_dir] = record
            outcome.skipped += 1
        else:
            outcome.stale += has_result(run)
            todo.append(run)
    outcome.submitted = len(todo)
    if on_start is not None:
        on_start(len(todo))
    if not todo:
        return outcome
    cfg = client.scatter(sweep.cfg, broadcast=True, hash=False)
    scenarios = {name: client.scatter(s, broadcast=True, hash=False) for name, s in sweep.scenarios.items()}
    tag = uuid.uuid4().hex[:8]
    futures = {client.submit(run_one, run, cfg, scenarios[run.scenario], pure=False, retries=0,
                             key=f"helicalib-sweep-{tag}-{run.cell}-seed-{run.seed}"): run for run in todo}
    try:
        for future in as_completed(futures):
            run = futures[future]
            if future.status == "finished":
                record = future.result()
                outcome.records[run.run_dir] = record
                reason = None
            else:
                record, reason, tb = None, *_failure(run, future)
                outcome.failures[run.run_dir] = (reason, tb)
            if on_result is not None:
                on_result(run, record, reason)
    finally:
        client.cancel(list(futures))
    return outcome


def _failure(run: Run, future) -> tuple[str, str]:
    """(one line: cell, seed, exception type and message; the worker's traceback)."""
    try:
        exc = future.exception()
    except Exception as err:  # noqa: BLE001 - a cancelled future raises here instead
        exc = err
    if isinstance(exc, RunFailed):
        what, tb = str(exc), exc.traceback_text
    else:  # the worker died (KilledWorker), the task was cancelled, ...
        what, tb = f"{type(exc).__name__}: {_one_line(exc)}", "".join(traceback.format_exception(exc))
    return f"cell {run.cell}, seed {run.seed}: {what}", tb


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or "(no message)"
