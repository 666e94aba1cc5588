"""The measurement seam: where a visit gets its spot measurements from.

The visit (:mod:`.visit`) asks a :class:`~helicalib.devices.protocols.SpotSensor` for a reference before the beam
arrives (:meth:`SpotSensor.before`) and for the spot once the heliostat holds on the board
(:meth:`SpotSensor.after`); it never knows what is behind it. :class:`CameraSensor` is the
production sensor, the board's camera and the vision (frames grabbed over HTTP or from the
simulated camera, T/GRLM annex A on the rectified board). A simulated sensor that skips the
frames altogether (``helicalib.sim.fast_sensor``) sits behind the same protocol.

Both return a :class:`Reading` with the same fields and the same reason codes; the frames a
reading carries are stored with its observation (none for a sensor that has no frames).

**A before frame that held another beam.** A reading whose before frame held another heliostat's
beam (light on the board in the before frame that is gone in the after frames) says so
(``Reading.before_beam``; reason ``ambient_change``). Both sensors can then take the before frame
again and judge the same after frames against it (``retake``): the visit moves its beam to the
standby point, waits until the other beams have left the board, and asks for it
(:func:`~.measure.retake_before`).

**Exposure.** A camera that takes an exposure (``Frame.exposure_ms`` not None, PLANT_INTERFACE
1.1) is exposed per visit by :class:`~.exposure.ExposurePolicy`: the before frame is taken at the
exposure chosen for the spot expected (DNI, distance, mirror, cleanliness) and the after frames at
the same one; valid readings teach the camera's gain. A reading refused as too bright or too faint
offers a corrected exposure (:meth:`CameraSensor.exposure_retake`), at which the visit takes the
before and after frames again (:func:`~.measure.retake_exposure`). A camera without exposure control
is never asked for one: its frames are grabbed as they always were.
"""

from __future__ import annotations

import inspect
import math
from collections import deque
from collections.abc import Callable, Generator

import numpy as np

from helicalib.campaign.exposure import AfterImages, BeforeState, ExposurePolicy, SpotFigures, board_grey, expected_peak_wm2
from helicalib.campaign.frames import FrameWorker, run_now
from helicalib.devices.protocols import Before, CaptureTimeError, Reading, SpotSensor
from helicalib.errors import HelicalibError, MeasurementError
from helicalib.flux.visit import cleanliness_from_visit
from helicalib.vision.frames import decode_frame
from helicalib.vision.marks import find_marks
from helicalib.vision.spot import SpotLimits, measure_spot

MARKS_REUSE_VISITS = 50
"""The board's marks serve this many visits of the same camera (board and camera do not move), then
they are found again; at once after a reading that doubts them."""
MARKS_MEAN_FRAMES = 8
"""The marks are found on the mean of the camera's last before frames, up to this many: the first
visit's own frame, then again once 8 are there (and at every later finding). Averaging takes the
sensor noise out of the board's fix: on the simulated plant's frames, exposed for the spot, the board
centre of a dot board came 0.005–0.025 px from the truth with black dots and 0.007–0.059 px with
light-grey ones, against 0.006–0.056 and 0.03–0.14 px from one frame (8 m layout, 8-bit mean); on
the 18 m layout with the mean in floating point, light-grey dots 0.014–0.034 px against 0.044–0.073
px RMS from single frames (docs/vision.md). When a
before frame alone shows no marks, this many frames of the same visit are averaged at once
(:meth:`CameraSensor.before`: a dimly lit board)."""
MARKS_DOUBT = frozenset({"marks_not_found", "reprojection"})
"""Reading reasons after which the cached marks are found again on the next before frame."""


class CameraSensor:
    """The board's camera and the vision: the production sensor.

    Parameters
    ----------
    camera : devices.protocols.Camera
        ``grab() -> Frame`` (HTTP camera, or the simulated one).
    camera_config : config.Camera
        Intrinsics, distortion, resolution.
    fe_wm2_per_grey : float, optional
        The camera's flux factor, for the measured cleanliness (None: not measured).
    atmosphere : str or None
        Attenuation model between mirror and board for the measured cleanliness.
    fe_exposure_ms : float, optional
        The exposure at which ``fe_wm2_per_grey`` holds [ms]; default: the camera's exposure in its
        first frame (before any was asked). Frames at another exposure scale Fe by the ratio.
    """

    def __init__(self, camera, camera_config, fe_wm2_per_grey: float | None = None, atmosphere: str | None = "clear",
                 fe_exposure_ms: float | None = None):
        self.camera, self.camera_config = camera, camera_config
        self.fe_wm2_per_grey, self.atmosphere = fe_wm2_per_grey, atmosphere
        self.fe_exposure_ms = fe_exposure_ms
        self.exposure = ExposurePolicy()
        self.exposure_control: bool | None = None
        """Whether the camera sets its exposure: None until its first frame says (``Frame.exposure_ms``)."""
        self._marks = None
        self._marks_uses = 0
        self._marks_frames = 0  # before frames the marks were last sought on
        self._recent: deque = deque(maxlen=MARKS_MEAN_FRAMES)  # the last before images
        self.frames: FrameWorker | None = None
        """The camera's frame worker in a live run (:func:`frames_off_thread`); None: grabs on
        the visit's thread (simulations on a virtual clock)."""

    # ------------------------------------------------------------------ frames
    def _grab(self, ctx, exposure_ms: float | None = None):
        """One frame and its image, waited for on this thread (:meth:`_grab_waiting`)."""
        return run_now(self._grab_waiting(ctx, exposure_ms, block=True))

    def _grab_waiting(self, ctx, exposure_ms: float | None = None, block: bool = False):
        """One frame and its image, at ``exposure_ms`` if given and the camera takes one (a camera
        whose frames carry no exposure is never asked); refused (:class:`CaptureTimeError`) unless its
        capture time lies within ``max_capture_skew_s`` (plus the clock's uncertainty) of the plant
        time around the grab. With a frame worker (:attr:`frames`, a live run) the grab runs on the
        camera's thread and this generator yields short waits until the frame is there (``block``:
        waited for, in the camera's order); without one, on this thread and without a wait."""
        frame, image, _done = yield from self._grab_then(ctx, exposure_ms, block)
        return frame, image

    def _grab_then(self, ctx, exposure_ms: float | None = None, block: bool = False, then=None):
        """:meth:`_grab_waiting`, and ``then(image)`` run on the camera's thread straight after the frame
        (a live run, not ``block``); returns ``(frame, image, done)``, ``done`` the finished future of
        ``then`` (None: not run there, the caller runs it)."""
        t0 = ctx.now()
        ask = exposure_ms is not None and self.exposure_control
        grab = (lambda: self.camera.grab(exposure_ms=exposure_ms)) if ask else self.camera.grab
        done = None
        if self.frames is None:
            frame, image = grab(), None
        elif block:
            frame, image = self.frames.now(grab)
        else:
            frame, image, done = yield from self.frames.fetch(grab, then)
        t1 = ctx.now()
        self._saw_exposure(frame.exposure_ms)
        slack = ctx.settings.max_capture_skew_s + (ctx.time_slack_s() if ctx.time_slack_s is not None else 0.0)
        t = float(frame.capture_time_s)
        if not (math.isfinite(t) and t0 - slack <= t <= t1 + slack):
            off = f"{t - t1:+.6g} s from" if math.isfinite(t - t1) else "nowhere near"
            raise CaptureTimeError(f"{ctx.heliostat_id}: the camera's capture time {t:.6g} lies {off} the plant "
                                   f"time of the grab (tolerance {slack:.1f} s): is the camera's clock set?", frame)
        return frame, image if image is not None else decode_frame(frame.data, expected_shape=None), done

    def _saw_exposure(self, exposure_ms: float | None) -> None:
        """What a frame says of the camera's exposure control (the first: Fe's reference exposure and
        the policy's prior gain from it)."""
        first = self.exposure_control is None
        self.exposure_control = exposure_ms is not None and _takes_exposure(self.camera)
        if first and self.exposure_control:
            if self.fe_exposure_ms is None:
                self.fe_exposure_ms = float(exposure_ms)
            if self.fe_wm2_per_grey:
                self.exposure.prior_gain = 1.0 / (self.fe_wm2_per_grey * self.fe_exposure_ms)

    def _expected_peak(self, ctx) -> float | None:
        """The visit's spot's expected peak irradiance [W/m²] now (None: the plant's weather or
        status cannot be read, or the context has no plant and model to ask)."""
        if getattr(ctx, "plant", None) is None or getattr(ctx, "model", None) is None:
            return None
        try:
            dni = float(ctx.plant.weather().dni_wm2)
            clean = float(ctx.plant.status(ctx.index).cleanliness)
        except HelicalibError:  # a plant that does not answer: the camera keeps its exposure
            return None
        sun = ctx.sun(ctx.now())[0]
        return expected_peak_wm2(
            dni, ctx.model.drives.mirror_size_m[0], ctx.model.pivots_enu[0], ctx.target.center_enu_m,
            ctx.target.frame_enu[2], sun, cleanliness=clean if math.isfinite(clean) else 1.0,
            reflectivity=ctx.settings.reflectivity_clean, atmosphere=self.atmosphere)

    def _marks_for(self, image, target):
        """The board's marks for this before ``image``: found on the mean of the last before frames
        (:data:`MARKS_MEAN_FRAMES`) when there are none yet, when they have served
        :data:`MARKS_REUSE_VISITS` visits, and once more when the frames to average first reach
        :data:`MARKS_MEAN_FRAMES` (kept as they were, until they expire, if that finding fails)."""
        if self._recent and self._recent[-1].shape != image.shape:
            self._recent.clear()
        self._recent.append(image)
        fresh = self._marks is None or self._marks_uses >= MARKS_REUSE_VISITS
        more = len(self._recent) == MARKS_MEAN_FRAMES and self._marks_frames < MARKS_MEAN_FRAMES
        if fresh or more:
            marks = find_marks(self._mean_before(), target, self.camera_config)
            self._marks_frames = len(self._recent)  # sought on this many: a failed mean is not sought again
            if marks.found:
                self._marks, self._marks_uses = marks, 0
            elif fresh:
                self._forget_marks()
                return marks
        self._marks_uses += 1
        return self._marks

    def _mean_before(self) -> np.ndarray:
        """The mean of the kept before images in floating point (the one image itself if alone): the dot
        finder centres dots on its fractions of a grey level, which an 8-bit mean would round away (on a
        dimly lit board that rounding moved the board centre by up to 0.04 px); L marks are found on it
        rounded to 8 bits."""
        if len(self._recent) == 1:
            return self._recent[0]
        return np.mean(np.stack(self._recent).astype(np.float32), axis=0)

    def _forget_marks(self) -> None:
        """Find the marks again on the next before frame alone (the board or the camera may have moved)."""
        self._marks, self._marks_uses, self._marks_frames = None, 0, 0
        self._recent.clear()

    # ------------------------------------------------------------------ the protocol
    def before(self, ctx, exposure_ms: float | None = None) -> Before:
        """The before frame, at ``exposure_ms`` (a retake's) or the exposure the policy chooses for
        the visit's spot (a camera with exposure control, known from its first frame: the first
        visit keeps the camera's own exposure). Waited for on this thread (:meth:`before_waiting`)."""
        return run_now(self.before_waiting(ctx, exposure_ms, block=True))

    def before_waiting(self, ctx, exposure_ms: float | None = None, block: bool = False
                       ) -> Generator[float, None, Before]:
        """:meth:`before` as a generator of plant-second waits: with a frame worker (a live run) it
        yields while its frames are on their way, so the loop steps the other boards meanwhile."""
        expected = self._expected_peak(ctx) if self.exposure_control else None
        want = exposure_ms if exposure_ms is not None else self.exposure.choose(expected)
        frame, image = yield from self._grab_waiting(ctx, want, block)
        marks = self._marks_for(image, ctx.target)
        if not marks.found:
            marks = yield from self._marks_on_more_frames(ctx, image, marks, frame.exposure_ms, block)
        board = None
        if frame.exposure_ms is not None:
            board = board_grey(image, marks, ctx.target)
            self.exposure.saw_board(board, frame.exposure_ms)
        return Before(capture_time_s=float(frame.capture_time_s), data=frame.data,
                      state=BeforeState(image, marks, frame.exposure_ms, expected, board))

    def _marks_on_more_frames(self, ctx, image, failed, exposure_ms=None, block: bool = True):
        """The marks sought once more on the mean of this frame and :data:`MARKS_MEAN_FRAMES` − 1 more
        grabbed now, when this frame alone shows none (beams are off the board during ``before``). On a
        board lit dimly (the camera exposed for the spot, a low sun: the board at some 10–15 grey levels)
        a light-grey dot lies a few levels below its white, under the finder's floor of 4 noise σ of
        one frame, and 8 frames halve that twice. The extra frames serve the board's fix only; the
        visit keeps ``image`` as its before frame. Returns ``failed`` when they show no marks either, or
        when a frame cannot be had (the visit then goes on and says ``marks_not_found``)."""
        frames = [image]
        try:
            for _ in range(MARKS_MEAN_FRAMES - 1):
                frames.append((yield from self._grab_waiting(ctx, exposure_ms, block))[1])
        except MeasurementError:
            return failed
        if any(f.shape != image.shape for f in frames):
            return failed
        self._recent.clear()
        self._recent.extend(frames)
        marks = find_marks(self._mean_before(), ctx.target, self.camera_config)
        self._marks_frames = len(self._recent)
        if not marks.found:
            self._forget_marks()
            return failed
        self._marks, self._marks_uses = marks, 1  # this visit uses them
        return marks

    def retake(self, ctx, before: Before, reading: Reading) -> tuple[Before, Reading]:
        """A new before frame (the beam at standby) and ``reading``'s after frames measured against it.

        The old before frame held another beam: it leaves the mean the marks are found on. The after
        frames were taken a few seconds earlier; the difference after − k·before still holds only the
        spot (``k`` takes up a change of daylight in between, as for any before frame). Raises
        :class:`MeasurementError` as :meth:`before` does."""
        if self._recent and before.state is not None and self._recent[-1] is before.state[0]:
            self._recent.pop()
        new = self.before(ctx, getattr(before.state, "exposure_ms", None))
        if reading.state is None:  # no after image to judge again (the reading failed before the vision)
            return new, reading
        return new, self._judge(ctx, new, reading.state, reading.frames, reading.capture_time_s)

    def after(self, ctx, before: Before) -> Generator[float, None, Reading]:
        """The after frames, a plant second apart (each fetched off the loop's thread in a live run:
        :attr:`frames`; there the spot is measured on the camera's thread straight after the last
        frame, and the reading judged on the loop's thread as soon as both are in)."""
        frames, images, reason, message, refused, done = [], [], None, "", [], None
        n = ctx.settings.after_frames
        for k in range(n):
            last = self.frames is not None and k == n - 1 and before.state is not None
            vision = self._vision(ctx, before, list(images)) if last else None
            try:
                f, img, done = yield from self._grab_then(ctx, getattr(before.state, "exposure_ms", None), then=vision)
                frames.append(f)
                images.append(img)
            except MeasurementError as err:
                reason, message = getattr(err, "reason", "bad_frame"), str(err)
                if isinstance(err, CaptureTimeError):
                    refused.append(err.frame.data)  # kept with the observation that refuses it
                break
            if n > 1 and not (self.frames is not None and k == n - 1):
                yield 1.0
        # the spot is the mean over the after frames, so its sun is the sun at their mean capture time
        capture_s = float(np.mean([f.capture_time_s for f in frames])) if frames else float(ctx.now())
        data = tuple(f.data for f in frames) + tuple(refused)
        if reason is not None:
            return Reading(False, reason, message, capture_s, frames=data)
        return self._judge(ctx, before, images, data, capture_s, None if done is None else done.result())

    def _vision(self, ctx, before: Before, earlier: list) -> Callable[[np.ndarray], object]:
        """The spot of ``earlier`` after images and one more against ``before``, as a pure function of
        that last image (it runs on the camera's thread in a live run: :meth:`after`)."""
        image, marks = before.state
        # the jitter limit as an angle: a far heliostat's beam wanders as many metres for less mrad
        distance_m = float(np.linalg.norm(np.asarray(ctx.target.center_enu_m, dtype=float) - ctx.model.pivots_enu[0]))
        limits = SpotLimits(max_jitter_m=1e-3 * ctx.settings.max_jitter_mrad * distance_m)
        target, camera, method = ctx.target, self.camera_config, ctx.settings.spot_method
        return lambda last: measure_spot(image, [*earlier, last], target, camera, method=method, marks=marks,
                                         limits=limits)

    def _judge(self, ctx, before: Before, images: list, data: tuple, capture_s: float, spot=None) -> Reading:
        """The reading of the after ``images`` against ``before`` (``data``: the frames to store);
        ``spot``: their spot measured already (on the camera's thread), else measured here. What the
        spot changes (the marks' doubt, the exposure's gain) changes here, on the loop's thread."""
        if spot is None:
            spot = self._vision(ctx, before, images[:-1])(images[-1])
        if spot.reason in MARKS_DOUBT:
            self._forget_marks()
        images = AfterImages(images)
        images.figures = self._figures(before, spot)
        if spot.valid and images.figures is not None:
            self.exposure.learn(images.figures, before.state.expected_peak)
        return Reading(
            valid=bool(spot.valid), reason=spot.reason, message=spot.message, capture_time_s=capture_s,
            offset_m=None if spot.offset_m is None else (float(spot.offset_m[0]), float(spot.offset_m[1])),
            spot_px=None if spot.spot_center_px is None else (float(spot.spot_center_px[0]),
                                                             float(spot.spot_center_px[1])),
            spot_area_px=_f(spot.spot_area_px), threshold=_f(spot.threshold), frames=data,
            before_beam=bool(spot.before_beam), state=images)

    @staticmethod
    def _figures(before: Before, spot) -> SpotFigures | None:
        """What the reading showed of the light, at the before frame's exposure (None: no control)."""
        exposure_ms = getattr(before.state, "exposure_ms", None)
        if exposure_ms is None:
            return None
        f = spot.frames[-1] if spot.frames else None
        sat = None if f is None or not math.isfinite(f.saturated_fraction) else float(f.saturated_fraction)
        return SpotFigures(exposure_ms, peak=None if f is None else float(f.peak),
                           noise=None if f is None else float(f.noise), saturated_fraction=sat,
                           board_grey=before.state.board_grey)

    def exposure_retake(self, before: Before, reading: Reading) -> float | None:
        """The exposure [ms] at which to take ``reading`` again (before and after frames), when it
        was refused as too bright or too faint and another exposure can mend it; else None (a camera
        without exposure control, a spot cut by the board's rim, the end of the camera's range)."""
        figures = getattr(reading.state, "figures", None)
        if reading.valid or figures is None:
            return None
        return self.exposure.retake_exposure_ms(reading.reason, figures)

    def cleanliness(self, ctx, before: Before, reading: Reading, held_mm: np.ndarray, weather,
                    sun_enu: np.ndarray) -> float | None:
        """The mirror's present cleanliness from the power in the spot (Zhang & Wang; docs/flux.md);
        Fe scaled to the frames' exposure."""
        image, marks = before.state
        held = np.asarray(held_mm, dtype=float).reshape(1, 2)
        fe = self.fe_wm2_per_grey
        exposure_ms = getattr(before.state, "exposure_ms", None)
        if fe is not None and exposure_ms is not None and self.fe_exposure_ms:
            fe = fe * self.fe_exposure_ms / exposure_ms
        est = cleanliness_from_visit(
            image, reading.state[-1], marks, ctx.target, fe_wm2_per_grey=fe,
            reflectivity_clean=ctx.settings.reflectivity_clean, dni_wm2=getattr(weather, "dni_wm2", None),
            sun_enu=sun_enu, pivot_enu=ctx.model.pivots_eff_enu[0], normal_enu=ctx.model.normal(held)[0],
            mirror_offset_m=float(ctx.model.mirror_offset_m[0]),
            mirror_area_m2=float(np.prod(ctx.model.drives.mirror_size_m[0])), atmosphere=self.atmosphere)
        return None if est.value is None else float(est.value)


def camera_sensors(cfg, cameras: dict, flux: dict | None = None) -> dict[str, CameraSensor]:
    """One :class:`CameraSensor` per board from the cameras (``target id → Camera``) a plant offers.

    ``flux``: target id → (Fe [W/m² per grey] or None, atmosphere model) of the board's camera, for
    the cleanliness measured from the spot; a board not in it takes its camera's FLUX.yaml from the
    field config (``flux_calibration``; none: no cleanliness is measured). A FLUX.yaml that cannot
    be read raises :class:`~helicalib.errors.ConfigError`. The camera itself is only a device
    (frames); the composition root that knows the plant gives its flux factors here (the simulated
    plant's: :func:`helicalib.sim.camera.simulated_flux`).
    """
    from helicalib.flux.config import flux_calibration_of

    out = {}
    for tid, cam in cameras.items():
        cam_cfg = cfg.cameras_for(tid)[0]
        fe, atmosphere = (flux or {}).get(tid) or flux_calibration_of(cfg, cam_cfg)
        out[tid] = CameraSensor(cam, cam_cfg, fe_wm2_per_grey=fe, atmosphere=atmosphere)
    return out


def _takes_exposure(camera) -> bool:
    """Whether ``camera.grab`` takes ``exposure_ms`` (a camera object made before interface 1.1, or a
    wrapper that does not pass it on, is driven as a camera without exposure control)."""
    try:
        return "exposure_ms" in inspect.signature(camera.grab).parameters
    except (TypeError, ValueError):
        return False


def _f(x) -> float | None:
    return None if x is None else float(x)


def frames_off_thread(sensors: dict, on_done: Callable[[], None] | None = None) -> Callable[[], None]:
    """Give every camera sensor among ``sensors`` (target id → spot sensor) a :class:`FrameWorker`
    (``on_done``: :attr:`FrameWorker.on_done`); returns the function that takes them back and closes
    them (a live run's end)."""
    given = {tid: s for tid, s in sensors.items() if isinstance(s, CameraSensor)}
    for tid, sensor in given.items():
        sensor.frames = FrameWorker(tid, on_done)

    def stop() -> None:
        for sensor in given.values():
            worker, sensor.frames = sensor.frames, None
            if worker is not None:
                worker.close()
    return stop
