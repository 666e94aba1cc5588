"""Run a sweep's runs on Dask distributed and gather them.

The cluster is :mod:`helicalib.app.cluster`'s, the same a split ``simulate`` uses:
:func:`embedded_cluster` starts a ``LocalCluster`` on 127.0.0.1, :func:`connect` joins an existing
scheduler (:func:`cluster_for` picks one). :func:`run_sweep` skips finished runs, submits the others (one task
= one whole simulation) and hands each outcome to a callback as it arrives, in completion order;
nothing a run computes depends on that order.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from dataclasses import dataclass, field

from helicalib.app.cluster import check_workers, connect, embedded_cluster, failure_of
from helicalib.app.cluster import cluster_for as _cluster_for
from helicalib.sweep.spec import PROGRESS_EVERY, Run, Sweep
from helicalib.sweep.task import finished_record, has_result, run_one

__all__ = ["Outcome", "check_workers", "cluster_for", "connect", "embedded_cluster", "run_sweep"]


@dataclass
class Outcome:
    """What became of each run of one sweep invocation."""

    records: dict[str, dict] = field(default_factory=dict)      # run_dir → record (finished now or before)
    failures: dict[str, tuple[str, str]] = field(default_factory=dict)  # run_dir → (one-line reason, traceback)
    skipped: int = 0        # finished before with the same settings
    stale: int = 0          # finished before with other settings: run again
    submitted: int = 0


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
    what, tb = failure_of(future)
    return f"cell {run.cell}, seed {run.seed}: {what}", tb


def cluster_for(scheduler: str | None, workers: int):
    """The sweep's cluster: the scheduler's (its workers checked on the sweep's task module) or an
    embedded one of ``workers`` processes."""
    return _cluster_for(scheduler, workers, "helicalib.sweep.task")
