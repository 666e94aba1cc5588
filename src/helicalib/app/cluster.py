"""The Dask cluster simulations run on: an embedded ``LocalCluster`` or an existing scheduler.

One place for both users, ``helicalib sweep`` (one task = one whole simulation) and a split
``helicalib simulate --workers N / --scheduler ADDR`` (one task = one group of boards):
:func:`cluster_for` opens either; :func:`embedded_cluster` starts worker processes with one
thread each on 127.0.0.1 (a simulation holds the GIL most of the time, so threads would take
turns); :func:`connect` joins a scheduler and refuses workers that cannot run this helicalib.
A task raises :class:`TaskFailed` (:func:`call_reporting`), which :func:`failure_of` turns into
one line and the worker's traceback.
"""

from __future__ import annotations

import logging
import traceback
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager

from helicalib.errors import ConfigError


class TaskFailed(Exception):
    """A task raised: the exception's type name, its message on one line and the worker's traceback
    (made on the worker: an exception's own attributes, such as an OSError's file name, do not
    always survive the trip to the client)."""

    def __init__(self, kind: str, message: str, traceback_text: str = ""):
        super().__init__(f"{kind}: {message}")
        self.kind, self.message, self.traceback_text = kind, message, traceback_text

    def __reduce__(self):
        return type(self), (self.kind, self.message, self.traceback_text)


def call_reporting(fn: Callable, *args, failure: type[TaskFailed] = TaskFailed):
    """``fn(*args)``; any exception comes out as ``failure`` (:class:`TaskFailed`) with its traceback."""
    try:
        return fn(*args)
    except Exception as exc:  # noqa: BLE001 - whatever a task raised, carried to the client in one piece
        raise failure(type(exc).__name__, one_line(exc), traceback.format_exc()) from None


def failure_of(future) -> tuple[str, str]:
    """(``kind: message`` on one line, the worker's traceback) of a future that did not finish."""
    try:
        exc = future.exception()
    except Exception as err:  # noqa: BLE001 - a cancelled future raises here instead
        exc = err
    if isinstance(exc, TaskFailed):
        return str(exc), exc.traceback_text
    # the worker died (KilledWorker), the task was cancelled, ...
    return f"{type(exc).__name__}: {one_line(exc)}", "".join(traceback.format_exception(exc))


def one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or "(no message)"


def cluster_for(scheduler: str | None, workers: int, task_module: str) -> AbstractContextManager:
    """A client of the scheduler at ``scheduler`` (:func:`connect`, its workers checked by importing
    ``task_module``) or, without one, of an embedded cluster of ``workers`` processes."""
    return connect(scheduler, task_module=task_module) if scheduler else embedded_cluster(workers)


@contextmanager
def embedded_cluster(workers: int) -> Iterator:
    """A client of a fresh ``LocalCluster`` of ``workers`` processes on 127.0.0.1, no dashboard; the
    cluster's own log is kept to critical messages (failed tasks are reported by their callers)."""
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.CRITICAL) as cluster, Client(cluster) as client:
        yield client


@contextmanager
def connect(address: str, timeout_s: float = 20.0, task_module: str = "helicalib.sweep.task") -> Iterator:
    """A client of the scheduler at ``address`` whose workers can import helicalib's ``task_module``."""
    from dask.distributed import Client

    try:
        client = Client(address, timeout=timeout_s)
    except (OSError, TimeoutError, ValueError) as err:
        raise ConfigError(f"--scheduler {address}: cannot connect ({one_line(err)})") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except TimeoutError:
            raise ConfigError(f"--scheduler {address}: no worker joined within {timeout_s:g} s") from None
        try:
            versions = client.run(worker_check, task_module)
        except Exception as err:  # noqa: BLE001 - whatever a worker raised, said in one line
            raise ConfigError(f"--scheduler {address}: a worker cannot run helicalib ({type(err).__name__}: "
                              f"{one_line(err)}); install helicalib in the workers' environment") from None
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


def worker_check(task_module: str) -> str:
    """On a worker: import the module its tasks run and return the helicalib version."""
    import importlib

    from helicalib import __version__

    importlib.import_module(task_module)
    return __version__
