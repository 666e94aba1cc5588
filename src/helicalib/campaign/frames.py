"""Frames fetched off the tick's thread: one worker thread per camera in a live run.

A live tick steps the boards' visits one after another. A visit that fetched its frames itself
would hold the tick for each frame (a fraction of a real second over HTTP; at a plant rate of 10×
several plant seconds), and every other board's visit would wait for it. With a
:class:`FrameWorker` the camera's grab (and the image's decoding) runs on the camera's own thread,
while the visit's generator yields :data:`FRAME_POLL_S` waits until the frame is there, so the
tick goes on with the other boards. One thread per camera keeps a camera's grabs in the order they
were asked and never two at once. The frame keeps the capture time the camera gave it.

A reading's last frame takes its vision along (``fetch(grab, then)``): the spot is measured on the
camera's thread straight after the frame is decoded, and the visit waits for both, so neither the
vision (tens of real milliseconds a reading) nor a look of the tick between frame and vision holds
the other boards. ``then`` is pure (images in, a result out); what the result changes in the sensor
and the reading made of it stay on the tick's thread.

A grab that fails raises its error where the visit waits for it (as a grab on the tick's thread
would: an invalid reading with its reason, or the visit's fault); so does an error of ``then``.
Simulations on a virtual clock never get a worker: their grabs and vision stay on the loop's
thread, frame for frame as before.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from helicalib.devices.protocols import Frame
from helicalib.vision.frames import decode_frame

FRAME_POLL_S = 0.25
"""Plant seconds a visit waits between looks at a frame still on its way (less than a live tick's
:data:`~helicalib.app.live.TICK_PLANT_S`: the visit is looked at again on the next tick)."""


class FrameWait(float):
    """A visit's wait for a frame on its way (:data:`FRAME_POLL_S`): a live tick steps such a visit
    again before it ends (:meth:`~.loop.CampaignRunner.tick`), so a frame that came in meanwhile is
    used at once."""


class FrameWorker:
    """One camera's grabs on a thread of their own (module docstring)."""

    def __init__(self, name: str, on_done: Callable[[], None] | None = None):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"helicalib-camera-{name}")
        self.on_done = on_done
        """Called (on the camera's thread) when a frame a visit waits for is in, with its vision if
        asked: a live run's tick then runs at once (:mod:`helicalib.app.live`), not at its next period."""

    def submit(self, grab: Callable[[], Frame]) -> Future:
        """``grab()`` on the camera's thread; the future's result is ``(frame, image)``, the image
        decoded there (None when it cannot be: the caller decodes it again for the error)."""
        return self._pool.submit(_fetch, grab)

    def fetch(self, grab: Callable[[], Frame], then: Callable[[np.ndarray], object] | None = None
              ) -> Generator[float, None, tuple[Frame, np.ndarray | None, Future | None]]:
        """``(frame, image, done)`` of ``grab()``, yielding :data:`FRAME_POLL_S` plant seconds until it is
        there; the grab's error is raised here. ``then``: run on the image on this camera's thread
        straight after it (not when the image cannot be decoded: its result is then None), waited for
        too; ``done`` is its finished future (None without ``then``), whose ``result()`` raises its error."""
        fut = self.submit(grab)
        done = None if then is None else self._pool.submit(_then, fut, then)
        last = fut if done is None else done
        if self.on_done is not None:
            last.add_done_callback(self._tell)
        while not last.done():
            yield FrameWait(FRAME_POLL_S)
        frame, image = fut.result()
        return frame, image, done

    def _tell(self, _fut: Future) -> None:
        try:
            self.on_done()
        except Exception:  # noqa: BLE001 - a tick asked early is a hurry, never a frame's failure
            pass

    def now(self, grab: Callable[[], Frame]) -> tuple[Frame, np.ndarray | None]:
        """``(frame, image)`` of ``grab()``, waited for (a step that cannot yield: still in the camera's order)."""
        return self.submit(grab).result()

    def close(self) -> None:
        """No more grabs; one on its way ends on its own (its visit was stopped)."""
        self._pool.shutdown(wait=False, cancel_futures=True)


def _fetch(grab: Callable[[], Frame]) -> tuple[Frame, np.ndarray | None]:
    frame = grab()
    try:
        image = decode_frame(frame.data, expected_shape=None)
    except Exception:  # noqa: BLE001 - decoded again on the visit's side, where its error belongs
        image = None
    return frame, image


def _then(fetched: Future, then: Callable[[np.ndarray], object]):
    """``then(image)`` once ``fetched`` (a job before this one on the same thread) is done; None when
    its grab failed or its image could not be decoded (that error is the visit's, from ``fetched``)."""
    if fetched.exception() is not None:
        return None
    _frame, image = fetched.result()
    return None if image is None else then(image)


def run_now(steps: Generator):
    """The value of a generator of waits that does not wait (a grab on the caller's thread)."""
    try:
        wait = next(steps)
    except StopIteration as done:
        return done.value
    steps.close()
    raise RuntimeError(f"a step that cannot wait asked to wait {wait} s")
