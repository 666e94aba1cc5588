"""The probe's judgements (pure: a reading in, a check out) and its views: plausible weather,
the plant clock against UTC, a heliostat's read-back, a frame's capture time and exposure, and a
big field's rows collapsed to the failures and a count line.
"""

from __future__ import annotations

import io
import json
import math

import pytest

from helicalib.app.probe import EXIT_MISMATCH, ProbeResult
from helicalib.app.probe_checks import (CLOCK_OFF_UTC_S, MISMATCH, OK, PLAUSIBLE, SKIPPED, WARNING,
                                        capture_time_check, clock_checks, exposure_check, frame_check,
                                        heliostat_check, skipped_check, weather_checks)
from helicalib.app.probe_view import COLLAPSE_ABOVE, as_json, print_json, print_table, shown_checks
from helicalib.devices.protocols import HeliostatStatus, Weather
from helicalib.devices.registers import HeliostatState

GOOD = dict(wind_ms=4.0, wind_direction_deg=200.0, dni_wm2=850.0, temperature_c=21.0, pressure_hpa=880.0)
LIMITS = [(0.0, 1850.0), (0.0, 1590.0)]


@pytest.mark.parametrize("key", list(PLAUSIBLE))
@pytest.mark.parametrize("where", ["low", "high", "nan"])
def test_each_weather_quantity_outside_its_range_is_a_mismatch_naming_it(key, where):
    lo, hi, unit, name = PLAUSIBLE[key]
    value = {"low": lo - 0.5, "high": hi + 0.5, "nan": math.nan}[where]
    checks = weather_checks(Weather(**{**GOOD, key: value}))
    bad = [c for c in checks if c.status != OK]
    assert [c.name for c in bad] == [name] and bad[0].status == MISMATCH and "implausible" in bad[0].found
    assert all(c.status == OK for c in weather_checks(Weather(**{**GOOD, key: lo}))
               + weather_checks(Weather(**{**GOOD, key: hi})))


def test_a_real_plants_clock_hours_off_utc_is_a_warning_a_simulators_is_not_compared():
    utc = 1.8e9
    rate, on_time = clock_checks(utc + 2.0, 1.0, utc)
    assert rate.status == OK and on_time.status == OK
    _rate, off = clock_checks(utc - 3 * 3600.0, 1.0, utc)
    assert off.status == WARNING and "-3.0 h from UTC" in off.found and off.values["off_s"] == -3 * 3600.0
    _rate, just = clock_checks(utc + CLOCK_OFF_UTC_S + 1.0, 1.0, utc)
    assert just.status == WARNING
    _rate, sim = clock_checks(utc - 3 * 3600.0, 200.0, utc)
    assert sim.status == OK and "simulator" in sim.found


@pytest.mark.parametrize("rate", [0.0, -1.0, math.inf, math.nan])
def test_a_clock_rate_not_positive_and_finite_is_a_mismatch(rate):
    checks = clock_checks(1.8e9, rate, 1.8e9)
    assert checks[0].name == "plant clock rate" and checks[0].status == MISMATCH


def _status(state=HeliostatState.TRACKING, fault=0, strokes=(900.0, 800.0), clean=0.95):
    return HeliostatStatus(index=0, state=state, sequence_done=0, fault=fault, strokes_mm=strokes, cleanliness=clean)


def test_a_heliostat_read_back_in_range_is_ok():
    c = heliostat_check("H0001", _status(), LIMITS)
    assert c.status == OK and c.name == "H0001" and c.values["state"] == "tracking"


@pytest.mark.parametrize("strokes, ok", [((1850.0 + 18.0, 800.0), True), ((1850.0 + 19.0, 800.0), False),
                                         ((-15.0, 800.0), True), ((900.0, -16.0), False),
                                         ((math.nan, 800.0), False)])
def test_strokes_may_overrun_their_range_by_one_percent_of_it(strokes, ok):
    c = heliostat_check("H0002", _status(strokes=strokes), LIMITS)
    assert (c.status == OK) is ok, c.found
    if not ok:
        assert c.status == MISMATCH and "outside" in c.found


@pytest.mark.parametrize("clean", [-0.01, 1.01, 3.0, math.nan])
def test_cleanliness_outside_0_1_is_a_mismatch(clean):
    c = heliostat_check("H0003", _status(clean=clean), LIMITS)
    assert c.status == MISMATCH and c.found.startswith("cleanliness ") and "outside 0..1" in c.found


def test_a_heliostat_in_fault_is_a_warning_naming_its_fault_and_an_unknown_state_a_mismatch():
    c = heliostat_check("H0004", _status(state=HeliostatState.FAULT, fault=1), LIMITS)
    assert c.status == WARNING and c.found == "state fault; fault 1 (stroke out of range)"
    c = heliostat_check("H0004", _status(fault=9), LIMITS)
    assert c.status == WARNING and "an unknown code" in c.found

    class Odd:  # a plant client that passes a state through undecoded
        state, fault, strokes_mm, cleanliness = 17, 0, (900.0, 800.0), 0.9

    c = heliostat_check("H0004", Odd(), LIMITS)
    assert c.status == MISMATCH and "state 17 unknown" in c.found


def test_a_capture_time_outside_the_grab_by_more_than_the_skew_is_a_camera_clock_off():
    assert capture_time_check("C1", 1005.0, 1000.0, 1010.0, 5.0).status == OK  # within the grab
    assert capture_time_check("C1", 1014.9, 1000.0, 1010.0, 5.0).status == OK
    late = capture_time_check("C1", 1015.5, 1000.0, 1010.0, 5.0)
    assert late.status == MISMATCH and late.found == "camera clock off by +5.5 s"
    early = capture_time_check("C1", 994.0, 1000.0, 1010.0, 5.0)
    assert early.status == MISMATCH and early.found == "camera clock off by -6 s"
    assert capture_time_check("C1", math.nan, 1000.0, 1010.0, 5.0).status == MISMATCH


def test_frame_size_against_the_configured_resolution():
    assert frame_check("C1", (1280, 1024), (1280, 1024)).status == OK
    assert frame_check("C1", (1280, 1024), None).status == OK
    bad = frame_check("C1", (640, 512), (1280, 1024))
    assert bad.status == MISMATCH and "640×512" in bad.found
    assert frame_check("C1", None, None, "refused").status == MISMATCH


def test_exposure_support_is_reported_and_a_request_not_applied_is_a_warning():
    none = exposure_check("C1", None, 2.0, None)
    assert none.status == OK and none.found.startswith("exposure 1.1: no")
    applied = exposure_check("C1", 1.5, 3.0, 3.0)
    assert applied.status == OK and applied.found == "exposure 1.1: yes, 1.5 ms; asked 3 ms: applied"
    clamped = exposure_check("C1", 1.5, 3.0, 2.5)
    assert clamped.status == OK and "applied 2.5 ms" in clamped.found
    ignored = exposure_check("C1", 1.5, 3.0, None)
    assert ignored.status == WARNING and "not applied" in ignored.found


def _big_result(n: int, bad: set[int]) -> ProbeResult:
    checks = [heliostat_check(f"H{k:05d}", _status(clean=3.0 if k in bad else 0.9), LIMITS) for k in range(n)]
    checks += weather_checks(Weather(**GOOD))
    return ProbeResult("f.yaml", "Modbus TCP 127.0.0.1:502 unit 1", tuple(checks))


def test_a_big_field_shows_its_failures_and_a_count_line_unless_all():
    result = _big_result(10_000, {17, 9_001})
    rows = shown_checks(result.checks)
    helio = [c for c in rows if c.section == "heliostats"]
    assert [c.name for c in helio] == ["heliostats read", "H00017", "H09001"]
    assert helio[0].found == "9998 ok, 2 mismatch, 0 warning"
    assert len(shown_checks(result.checks, show_all=True)) == len(result.checks)
    assert result.exit_status == EXIT_MISMATCH
    out = io.StringIO()
    print_table(result, stream=out)
    text = out.getvalue()
    assert len(text.splitlines()) < 40 and "H00017" in text and "H00018" not in text
    assert "MISMATCH: heliostats: H09001: cleanliness 3 outside 0..1" in text


def test_a_small_field_shows_every_row():
    result = _big_result(COLLAPSE_ABOVE, set())
    assert len(shown_checks(result.checks)) == len(result.checks) and result.exit_status == 0


def test_json_is_strict_even_for_values_that_are_not_numbers():
    checks = (heliostat_check("H1", _status(clean=math.nan), LIMITS), skipped_check("cameras", "C9 frame", "why"))
    result = ProbeResult("f.yaml", "p", checks)
    out = io.StringIO()
    print_json(result, stream=out)
    doc = json.loads(out.getvalue())  # no bare NaN
    assert doc["checks"][0]["values"]["cleanliness"] == "nan"
    assert doc["summary"][MISMATCH] == 1 and doc["summary"][SKIPPED] == 1 and doc["summary"]["exit_status"] == 1
    assert as_json(result)["summary"]["heliostats"] == {"read": 1, "ok": 0, "mismatch": 1, "warning": 0}
