"""Track commands of many heliostats in flight at once over Modbus TCP (a tracking refresh round).

One track command by the map's handshake is three round trips (the block read, the corrections,
the sequence number); one after another, a refresh of 10⁴ heliostats takes longer than its
15-minute period at a plant rate of 10× (docs/benchmarks.md). :class:`TrackBatch` sends a batch's
commands on :data:`BATCH_LINKS` connections of their own to the plant's endpoint, one command per
connection at a time (pymodbus's synchronous client serves one request at a time; each link is
used by one thread at a time). The rules of a single command hold for each: ``armed``, the
corrections checked (:class:`~.guard.CommandGuard`), the handshake, the execute write sent once; the
commands of a batch hold the stow gate's lock together (:meth:`~.guard.GateLock.shared`), so a STOW
ALL waits for those in flight and none asked after it is sent. An endpoint that takes no client
beside the SCS connection (a link that never connects while that one answers) gets the commands one
at a time on the SCS connection (:attr:`TrackBatch.direct`).
"""

from __future__ import annotations

import queue
from concurrent.futures import Future, ThreadPoolExecutor

from helicalib.devices.modbus_link import ModbusLink
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.errors import PlantError

BATCH_LINKS = 4
"""Connections (and commands in flight) of a batch. Modbus TCP servers take several clients at
once (many a gateway at least 4); the plant's own SCS connection stays free for the visits."""


class Sent:
    """A batch of track commands on its way: :meth:`done` once every command has been answered or
    refused; :meth:`results` per item, in order, None (taken) or the refusal (waits for them);
    :attr:`direct` why the batch's commands went one at a time on the SCS connection (None: they
    did not)."""

    def __init__(self, futures: list[Future], batch: TrackBatch | None = None):
        self._futures = futures
        self._batch = batch

    @property
    def direct(self) -> str | None:
        return None if self._batch is None else self._batch.direct

    def done(self) -> bool:
        return all(f.done() for f in self._futures)

    def results(self) -> list[PlantError | None]:
        return [f.result() for f in self._futures]


class TrackBatch:
    """A :class:`~.modbus.ModbusPlant`'s track commands several at a time (module docstring)."""

    def __init__(self, plant, links: int = BATCH_LINKS):
        e = plant.scs
        kw = plant._link_kw
        self.plant = plant
        self.links = [ModbusLink(e.host, e.port, e.unit, **kw) for _ in range(max(1, int(links)))]
        self._free: queue.SimpleQueue[ModbusLink] = queue.SimpleQueue()
        for link in self.links:
            self._free.put(link)
        self._pool = ThreadPoolExecutor(max_workers=len(self.links), thread_name_prefix="helicalib-track")
        self.direct: str | None = None
        """Why the commands go one at a time on the SCS connection (None: on the batch's links). Set
        when a batch link cannot connect while the SCS connection answers: a plant or gateway that
        takes one client only keeps its refresh, as before batches, one command at a time."""

    def _one(self, index: int, corrections_mm) -> PlantError | None:
        if self.direct is None:
            link = self._free.get()
            try:
                err = self._track(index, corrections_mm, link)
                if not isinstance(err, PlantUnreachableError) or link.answered or not self._scs_answers(index):
                    return err
            finally:
                self._free.put(link)
            # nothing was sent on a link that never connected, while the SCS connection answers: the
            # endpoint takes no more clients, so this command and all after it go on that one
            self.direct = f"{err} (the endpoint took no connection beside the SCS one)"
        return self._track(index, corrections_mm)

    def _track(self, index: int, corrections_mm, link: ModbusLink | None = None) -> PlantError | None:
        """One track command on ``link`` (None: the SCS connection); its refusal, or None (taken)."""
        try:
            self.plant.track(index, corrections_mm, link=link)
        except PlantError as err:
            return err
        except Exception as err:  # noqa: BLE001 - a worker's error is the command's answer, never lost
            return PlantError(f"track command to {self.plant._label(index)}: {type(err).__name__}: {err}")
        return None

    def _scs_answers(self, index: int) -> bool:
        """Whether the SCS connection answers now (the heliostat's status read on it): a plant that is
        down is not an endpoint that takes one client."""
        try:
            self.plant.status(index)
        except Exception:  # noqa: BLE001 - any failure: not known to answer
            return False
        return True

    def send(self, items) -> Sent:
        """The track commands of ``items`` ``[(index, corrections_mm), ...]`` on their way (the caller goes on)."""
        return Sent([self._pool.submit(self._one, int(i), c) for i, c in items], self)

    def hurry(self) -> None:
        for link in self.links:
            link.hurry()

    def close(self) -> None:
        self._pool.shutdown(wait=True)
        for link in self.links:
            link.close()
