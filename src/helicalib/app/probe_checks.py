"""What ``helicalib probe`` judges: each reading of a live plant against its field config and the
physically plausible, as one :class:`Check` (pure: values in, a check out; no device, no clock).

A check is ``ok``, ``mismatch`` (the plant, its map or a camera disagrees with the config, or a
value no plant can have: probe exits non-zero), ``warning`` (worth a look, not wrong: a heliostat
in fault, a real plant's clock hours off UTC) or ``skipped`` (not read, because an earlier check
failed; the earlier one says why).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

OK, MISMATCH, WARNING, SKIPPED = "ok", "mismatch", "warning", "skipped"
STATUSES = (OK, MISMATCH, WARNING, SKIPPED)

PLAUSIBLE = {
    "wind_ms": (0.0, 75.0, "m/s", "wind speed"),
    "wind_direction_deg": (0.0, 360.0, "°", "wind direction"),
    "dni_wm2": (0.0, 1400.0, "W/m²", "DNI"),
    "temperature_c": (-60.0, 70.0, "°C", "air temperature"),
    "pressure_hpa": (500.0, 1100.0, "hPa", "air pressure"),
}
"""Weather quantity → (low, high, unit, name): what a weather station on Earth can read (the
strongest gusts measured are under 75 m/s, the solar constant is 1361 W/m², the highest plants
stand under 5000 m: above 500 hPa)."""
CLOCK_OFF_UTC_S = 60.0
"""A plant clock at rate 1 further than this from the computer's UTC is a warning: one of the two
clocks is not set (a time server keeps both within a second)."""
STROKE_TOLERANCE_SHARE = 0.01
"""A stroke read back may lie this share of its drive's range outside the range (an end stop
overrun, a scaled integer's rounding) before it is a mismatch; further out, the map decodes the
wrong registers, words or scale."""
KNOWN_STATES = {0: "idle", 1: "tracking", 2: "moving", 3: "holding", 4: "stowed", 5: "fault", 6: "offline"}
KNOWN_FAULTS = {0: "none", 1: "stroke out of range", 2: "refused during stow", 3: "unknown command"}


@dataclass(frozen=True)
class Check:
    """One line of the probe's table: what was checked, what the config expects, what the plant
    gave, the verdict, and the values read (for ``--json``)."""

    section: str
    name: str
    expected: str
    found: str
    status: str
    values: dict = field(default_factory=dict)


def _fmt(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}" if math.isfinite(x) else repr(float(x))


def count_check(expected: int, found: int | None, error: str | None = None) -> Check:
    """The heliostat count the plant reports against the config's (``error``: the plant's answer
    refused, or no answer: the line names the endpoint)."""
    want = f"{expected} heliostats (the field config)"
    if error is not None:
        return Check("plant", "heliostat count", want, error, MISMATCH, {"expected": expected, "found": found})
    status = OK if found == expected else MISMATCH
    text = f"{found} heliostats" + ("" if status == OK else "; blocks are matched to the config by order")
    return Check("plant", "heliostat count", want, text, status, {"expected": expected, "found": found})


def clock_checks(t_s: float, rate: float, utc_s: float) -> list[Check]:
    """The plant clock: its rate (> 0, finite) and its time against the computer's UTC ``utc_s``
    (a warning when a rate-1 plant is more than :data:`CLOCK_OFF_UTC_S` off; a simulator's clock,
    rate ≠ 1, is not compared)."""
    from helicalib.devices.clock import iso_utc

    rate_ok = math.isfinite(rate) and rate > 0
    out = [Check("clock", "plant clock rate", "> 0 and finite (1 for a real plant)", f"{_fmt(rate)}",
                 OK if rate_ok else MISMATCH, {"rate": rate})]
    values = {"plant_time_s": t_s, "utc_s": utc_s}
    want = f"UTC now ±{CLOCK_OFF_UTC_S:g} s"
    if not math.isfinite(t_s):
        return out + [Check("clock", "plant time", want, f"{t_s!r}: not a time", MISMATCH, values)]
    off = t_s - utc_s
    values["off_s"] = off
    found = f"{iso_utc(t_s)} ({_off(off)} UTC)"
    if rate_ok and rate != 1.0:
        return out + [Check("clock", "plant time", want, f"{found}; a simulator's clock (rate {_fmt(rate)}): not "
                             "compared", OK, values)]
    status = OK if abs(off) <= CLOCK_OFF_UTC_S else WARNING
    if status == WARNING:
        found += ": is the plant's or this computer's clock set?"
    return out + [Check("clock", "plant time", want, found, status, values)]


def _off(off_s: float) -> str:
    """``+3.2 h from`` / ``-12 s from`` / ``on``."""
    if abs(off_s) < 0.5:
        return "on"
    if abs(off_s) >= 3600:
        return f"{off_s / 3600:+.1f} h from"
    if abs(off_s) >= 120:
        return f"{off_s / 60:+.1f} min from"
    return f"{off_s:+.1f} s from"


def weather_checks(weather) -> list[Check]:
    """Each weather quantity within :data:`PLAUSIBLE` (a value outside: a map decoding the wrong
    registers, word order or scale, or a broken sensor)."""
    out = []
    for key, (lo, hi, unit, name) in PLAUSIBLE.items():
        value = float(getattr(weather, key))
        ok = math.isfinite(value) and lo <= value <= hi
        out.append(Check("weather", name, f"{lo:g}..{hi:g} {unit}", f"{_fmt(value, 5)} {unit}"
                         + ("" if ok else ": implausible"), OK if ok else MISMATCH, {key: value}))
    return out


def heliostat_check(heliostat_id: str, status, limits_mm) -> Check:
    """One heliostat's read-back: a known state, its fault code, each stroke within its drive's
    range (± :data:`STROKE_TOLERANCE_SHARE` of the range), cleanliness 0..1. ``limits_mm`` is
    ``[(min, max), (min, max)]`` of its two actuators."""
    state, fault = int(status.state), int(status.fault)
    strokes = [float(s) for s in status.strokes_mm]
    clean = float(status.cleanliness)
    ranges = "/".join(f"[{lo:g}, {hi:g}]" for lo, hi in limits_mm)
    expected = f"known state, fault 0, strokes in {ranges} mm, cleanliness 0..1"
    mismatches, warnings = [], []
    if state not in KNOWN_STATES:
        mismatches.append(f"state {state} unknown")
    elif state in (5, 6):
        warnings.append(f"state {KNOWN_STATES[state]}")
    if fault:
        warnings.append(f"fault {fault} ({KNOWN_FAULTS.get(fault, 'an unknown code')})")
    for k, (s, (lo, hi)) in enumerate(zip(strokes, limits_mm), start=1):
        slack = STROKE_TOLERANCE_SHARE * (hi - lo)
        if not (math.isfinite(s) and lo - slack <= s <= hi + slack):
            mismatches.append(f"stroke {k} {_fmt(s, 6)} mm outside [{lo:g}, {hi:g}] mm")
    if not (math.isfinite(clean) and 0.0 <= clean <= 1.0):
        mismatches.append(f"cleanliness {_fmt(clean)} outside 0..1")
    values = {"state": KNOWN_STATES.get(state, state), "fault": fault, "strokes_mm": strokes, "cleanliness": clean}
    if mismatches or warnings:
        return Check("heliostats", heliostat_id, expected, "; ".join(mismatches + warnings),
                     MISMATCH if mismatches else WARNING, values)
    found = f"{KNOWN_STATES[state]}, strokes {_fmt(strokes[0], 6)}/{_fmt(strokes[1], 6)} mm, cleanliness {clean:.3f}"
    return Check("heliostats", heliostat_id, expected, found, OK, values)


def unread_check(section: str, name: str, expected: str, error: str) -> Check:
    """A read the plant refused or did not answer (the error names the endpoint and what)."""
    return Check(section, name, expected, error, MISMATCH, {"error": error})


def skipped_check(section: str, name: str, why: str) -> Check:
    return Check(section, name, "", f"not read: {why}", SKIPPED, {})


def frame_check(camera_id: str, frame_size_px: tuple[int, int] | None, expected_px: tuple[int, int] | None,
                error: str | None = None) -> Check:
    """One frame: it came and decodes, at the configured ``resolution_px`` when one is given."""
    want = "a frame that decodes" + (f", {expected_px[0]}×{expected_px[1]} px" if expected_px else "")
    values = {"size_px": list(frame_size_px) if frame_size_px else None,
              "expected_px": list(expected_px) if expected_px else None}
    if error is not None:
        return Check("cameras", f"{camera_id} frame", want, error, MISMATCH, {**values, "error": error})
    w, h = frame_size_px
    if expected_px is not None and (w, h) != tuple(expected_px):
        return Check("cameras", f"{camera_id} frame", want, f"{w}×{h} px: not the configured size", MISMATCH, values)
    return Check("cameras", f"{camera_id} frame", want, f"{w}×{h} px", OK, values)


def capture_time_check(camera_id: str, capture_s: float, before_s: float, after_s: float, skew_s: float) -> Check:
    """The frame's capture time against the plant time read just before and just after the grab:
    further out than ``skew_s`` (``calibration.max_capture_skew_s`` and the clock's uncertainty),
    the camera's clock is off."""
    want = f"within {skew_s:.3g} s of the plant time of the grab"
    values = {"capture_time_s": capture_s, "plant_before_s": before_s, "plant_after_s": after_s, "skew_s": skew_s}
    if not math.isfinite(capture_s):
        return Check("cameras", f"{camera_id} capture time", want, f"{capture_s!r}: not a time", MISMATCH, values)
    off = capture_s - before_s if capture_s < before_s else (capture_s - after_s if capture_s > after_s else 0.0)
    values["off_s"] = off
    if abs(off) > skew_s:
        return Check("cameras", f"{camera_id} capture time", want, f"camera clock off by {off:+.6g} s", MISMATCH,
                     values)
    return Check("cameras", f"{camera_id} capture time", want, f"{off:+.3g} s", OK, values)


def exposure_check(camera_id: str, current_ms: float | None, asked_ms: float,
                   applied_ms: float | None, error: str | None = None) -> Check:
    """Exposure control (PLANT_INTERFACE 1.1): whether the camera reports its exposure, and whether
    an exposure asked for was applied. A camera without it is fine (the controller keeps its frames
    as they come); one that reports an exposure but ignores or fails a request is a warning."""
    values = {"exposure_ms": current_ms, "asked_ms": asked_ms, "applied_ms": applied_ms}
    name, want = f"{camera_id} exposure", "interface 1.1 (optional)"
    if current_ms is None and (applied_ms is None or error is not None):
        return Check("cameras", name, want, "exposure 1.1: no (the camera sets its own)", OK, values)
    found = f"exposure 1.1: yes, {current_ms:g} ms" if current_ms is not None else "exposure 1.1: on request only"
    if error is not None:
        return Check("cameras", name, want, f"{found}; asked {asked_ms:g} ms: {error}", WARNING,
                     {**values, "error": error})
    if applied_ms is None:
        return Check("cameras", name, want, f"{found}; asked {asked_ms:g} ms: not applied", WARNING, values)
    if not math.isclose(applied_ms, asked_ms, rel_tol=0.01):
        return Check("cameras", name, want, f"{found}; asked {asked_ms:g} ms, applied {applied_ms:g} ms (its range)",
                     OK, values)
    return Check("cameras", name, want, f"{found}; asked {asked_ms:g} ms: applied", OK, values)
