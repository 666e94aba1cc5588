"""Exposure retakes in a campaign (campaign/measure.py ``retake_exposure``, CameraSensor), on the
in-process simulated plant with rendered PNG frames and a real store: a reading too bright or too
faint at the camera's own exposure is taken again at a corrected one and comes out valid; the same
camera without exposure control keeps its refusal, and is never asked for an exposure."""

from __future__ import annotations

import pytest

from helicalib.campaign import measure
from helicalib.config import load_field_config

from campaign_helpers import inprocess_campaign

HID = "H0001"


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


class _Asked:
    """Wraps a simulated camera: notes the exposure asked at every grab."""

    def __init__(self, cam, sim, target):
        self.cam, self.asked = cam, []

    def grab(self, exposure_ms=None):
        self.asked.append(exposure_ms)
        return self.cam.grab(exposure_ms=exposure_ms)


def _first_reading(cfg, tmp_path, scenario: dict, exposure: bool, sub: str):
    """The first visit's first reading of HID, and the cameras' exposures asked."""
    scenario = {**scenario, "camera": {**scenario.get("camera", {}), "exposure": exposure}}
    runner, sim, store, cid, cams = inprocess_campaign(cfg, tmp_path / sub, 10, 3, [HID], camera=_Asked,
                                                       scenario=scenario)
    runner.run_until(sim.t_s + 900)
    obs = [o for o in store.observations(cid) if o.iteration == 0]
    store.close()
    assert obs, "no placement in 15 plant minutes"
    asked = [e for c in cams.values() for e in c.asked]
    return obs[0], asked


BRIGHT = {"camera": {"gain_counts_per_wm2": 1.2}}
"""A camera six times as sensitive as the default: the spot saturates at the nominal exposure."""
FAINT = {"optics": {"reflectivity": 0.09}}
"""Mirrors a tenth as reflective: the spot is faint on a board lit as usual."""


@pytest.mark.parametrize("scenario, refused, longer", [(BRIGHT, ("saturated", "clipped"), False),
                                                       (FAINT, ("low_contrast",), True)])
def test_a_too_bright_or_too_faint_reading_is_retaken_at_a_corrected_exposure(cfg, tmp_path, scenario, refused,
                                                                              longer):
    fixed, asked = _first_reading(cfg, tmp_path, scenario, False, "fixed")
    assert not fixed.valid and fixed.reason in refused, (fixed.reason, fixed.message)
    assert set(asked) == {None}  # a camera without exposure control is never asked
    assert fixed.exposure_ms is None  # and its readings are stored without one

    first, asked = _first_reading(cfg, tmp_path, scenario, True, "exposure")
    assert first.valid, (first.reason, first.message)
    assert measure.EXPOSED in first.message and f"after a {fixed.reason} reading" in first.message
    retaken = [e for e in asked if e not in (None, 1.0)]  # the first visit: the camera's own (nominal) 1 ms
    assert retaken and all((e > 1.0) if longer else (e < 1.0) for e in retaken)
    assert first.exposure_ms == pytest.approx(retaken[-1])  # stored: the exposure of the retaken frames
    # the flux factor follows the exposure: the power in the spot is the mirror's (relative to a clean 0.93)
    reflect = scenario.get("optics", {}).get("reflectivity", 0.93) / 0.93
    assert first.cleanliness_measured == pytest.approx(first.cleanliness * reflect, rel=0.1)


def test_a_camera_without_exposure_control_keeps_its_readings(cfg, tmp_path):
    """The same visits with a camera that reports no exposure (scenario ``camera.exposure: false``)
    and with a camera object of the interface before 1.1 (``grab()`` only): the same readings."""

    class Plain:
        def __init__(self, cam, sim, target):
            self.cam = cam

        def grab(self):
            return self.cam.grab()

    out = []
    for sub, wrap in (("a", _Asked), ("b", Plain)):
        runner, sim, store, cid, cams = inprocess_campaign(cfg, tmp_path / sub, 10, 3, [HID, "H0012"], camera=wrap,
                                                           scenario={"camera": {"exposure": False}})
        runner.run_until(sim.t_s + 1800)
        out.append([(o.heliostat_id, o.iteration, o.valid, o.reason, o.offset_u_m, o.offset_v_m)
                    for o in store.observations(cid)])
        store.close()
    assert len(out[0]) >= 2 and out[0] == out[1]
