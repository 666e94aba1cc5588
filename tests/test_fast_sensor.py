"""The fast sensor (sim/fast_sensor.py) against the camera + vision on the same visits, and a fast
simulated campaign end to end (real store, no frames)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from campaign_helpers import inprocess_campaign
from helicalib.campaign.sensor import camera_sensors
from helicalib.app.simulated import SimulationOptions, simulate_campaign, default_start_s
from helicalib.config import load_field_config
from helicalib.sim.fast_sensor import MODEL_PATH, FastSensor, SensorErrorModel
from helicalib.store.sqlite import Store


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


class _Both:
    """The camera sensor, with the fast sensor asked for the same spot at the same instant."""

    def __init__(self, camera, fast, pairs):
        self.camera, self.fast, self.pairs = camera, fast, pairs

    def before(self, ctx):
        b = self.camera.before(ctx)
        self._fast_before = self.fast.before(ctx)
        return b

    def after(self, ctx, before):
        reading = yield from self.camera.after(ctx, before)
        fast = yield from self.fast.after(ctx, self._fast_before)
        self.pairs.append((reading, fast, self.fast.spot(ctx.index)))
        return reading

    def retake(self, ctx, before, reading):
        return self.camera.retake(ctx, before, reading)

    def cleanliness(self, *args):
        return self.camera.cleanliness(*args)


def test_fast_and_rendered_measurements_agree_within_the_modelled_spread(cfg, tmp_path):
    from helicalib.sim.camera import SimCamera

    pairs = []
    model = SensorErrorModel.load()

    def sensor(cam, sim, target):
        return _Both(camera_sensors(cfg, {target.id: cam})[target.id], FastSensor(sim, target.id, model, 5), pairs)

    runner, sim, store, _cid, _ = inprocess_campaign(cfg, tmp_path, 8, 5, ["H0001", "H0012", "H0025", "H0038"],
                                                     camera=lambda cam, s, t: sensor(cam, s, t))
    assert all(isinstance(c, SimCamera) for c in [p.camera.camera for p in runner.devices.sensors.values()])
    runner.run_until(sim.t_s + 4 * 3600)
    store.close()
    both = [(r, f, s) for r, f, s in pairs if r.valid and f.valid]
    assert len(both) >= 15
    assert sum(r.valid == f.valid for r, f, _s in pairs) >= 0.95 * len(pairs)
    for r, f, s in both:
        # both measure the same true spot: their difference within 5 sigma of the two spreads
        spread = np.hypot(model.spread_m(s.sigma_m), model.spread_m(s.sigma_m))
        assert np.all(np.abs(np.subtract(r.offset_m, f.offset_m)) <= 5 * spread + 1e-9), (r, f)


def test_a_fast_campaign_writes_no_frames_and_everything_else(cfg, tmp_path):
    res = simulate_campaign(cfg, tmp_path, SimulationOptions(0.25, seed=3, start_s=default_start_s(cfg) + 7 * 3600,
                                                             heliostat_ids=["H0001", "H0021"], fidelity="fast"))
    store = Store.open(res.database, readonly=True)
    obs, fits = store.observations(), store.fits()
    verdicts = store.latest_verdicts(store.campaigns()[-1].id)
    store.close()
    assert res.summary["fidelity"] == "fast" and res.summary["visits"] > 0
    assert obs and any(o.valid for o in obs) and fits and verdicts
    assert all(o.before_frame_path is None and not o.after_frame_paths for o in obs)
    assert not list(tmp_path.rglob("*.png"))
    assert all(o.cleanliness_measured is not None for o in obs if o.valid)


def test_the_shipped_model_says_what_it_was_fitted_on():
    data = json.loads(MODEL_PATH.read_text())
    fitted = data["fitted_on"]
    assert fitted["measurements"] > 100 and 0 < fitted["validity_agreement"] <= 1
    m = SensorErrorModel.load()
    # its spread is the rendered measurements' residual at a typical blur, within the fit's reach
    assert 0 < m.floor_m < 0.05 and m.per_sigma >= 0 and 0.1 <= m.threshold_fraction <= 0.6


def test_faint_spots_are_judged_on_the_fitted_contrast_scale_and_no_spot_fraction(cfg):
    """judge_spot's peak is linear in the spot's power: find the power at which the analytic peak
    crosses min_contrast (scale 1), then check the fitted scale and no-spot fraction move a faint
    spot's verdict exactly across the vision's limits."""
    from helicalib.sim.fast_sensor import SpotPhysics, judge_spot
    from helicalib.sim.scenario import parse_scenario
    from helicalib.vision.spot import SpotLimits

    target, spec, lim = cfg.targets[0], parse_scenario({}).camera, SpotLimits()

    def verdict(power, scale=1.0, no_spot=0.5):
        s = SpotPhysics(np.array([0.3, -0.2]), np.array([1.5, 1.2]), np.array([0.3, 0.3]), power, True)
        return judge_spot(s, target, spec, lim, 0.35, 100.0, 100.0, scale, no_spot)[0]

    lo, hi = 1.0, 1e7  # bisection on the low_contrast / ok edge (peak == min_contrast)
    assert verdict(lo) == "no_spot" and verdict(hi) != "low_contrast"
    for _ in range(80):
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if verdict(mid) in ("no_spot", "low_contrast") else (lo, mid)
    edge = hi
    assert verdict(0.7 * edge) == "low_contrast" and verdict(0.7 * edge, scale=1.5) == "ok"
    assert verdict(0.7 * edge, scale=1.4) == "low_contrast"  # 0.98 of the limit
    assert verdict(0.45 * edge) == "no_spot" and verdict(0.45 * edge, no_spot=0.3) == "low_contrast"
    assert verdict(0.55 * edge) == "low_contrast" and verdict(0.55 * edge, no_spot=0.6) == "no_spot"


def test_a_camera_with_exposure_control_is_exposed_as_the_policy_exposes_it(cfg):
    """policy_exposure puts the spot's brightest grey level (board light included) at TARGET_GREY,
    within the camera's range; judge_spot scales the light by
    the exposure and judges no_spot on the peak over the renderer's noise growth."""
    from helicalib.campaign.exposure import TARGET_GREY
    from helicalib.sim.camera import noise_scale
    from helicalib.sim.fast_sensor import SpotPhysics, judge_spot, peak_wm2, policy_exposure
    from helicalib.sim.scenario import parse_scenario
    from helicalib.vision.spot import SpotLimits

    target, spec, lim = cfg.targets[0], parse_scenario({}).camera, SpotLimits()
    gain = spec.gain_counts_per_wm2 * spec.board_albedo
    width, sigma = np.array([1.5, 1.2]), np.array([0.3, 0.3])

    def spot(power):
        return SpotPhysics(np.array([0.3, -0.2]), width, sigma, power, True)

    # the peak by direct numerical integration of the box ⊗ Gaussian profile at the spot's centre
    from scipy.integrate import quad

    per_axis = [quad(lambda t, s=s: np.exp(-0.5 * (t / s) ** 2), -w / 2, w / 2, epsabs=0, epsrel=1e-12)[0]
                / (np.sqrt(2 * np.pi) * s * w) for w, s in zip(width, sigma)]
    assert peak_wm2(spot(1e4)) == pytest.approx(1e4 * per_axis[0] * per_axis[1], rel=1e-6)

    ambient = 100.0  # board at 18 grey levels at the nominal exposure
    bright = spot(2e4)
    e = policy_exposure(bright, spec, ambient)
    assert gain * e * (ambient + peak_wm2(bright)) == pytest.approx(TARGET_GREY)
    faint = spot(100.0)
    narrow = spec.model_copy(update={"exposure_range_ms": (0.5, 2.0)})
    assert policy_exposure(faint, spec, ambient) > 2.0
    assert policy_exposure(faint, narrow, ambient) == pytest.approx(2.0)
    assert policy_exposure(spot(1e7), narrow, ambient) == pytest.approx(0.5)

    # a faint spot: low contrast at the nominal exposure, read at the policy's
    peak_nominal = gain * peak_wm2(faint)
    assert peak_nominal < lim.min_contrast
    e = policy_exposure(faint, spec, ambient)
    assert e * peak_nominal >= lim.min_contrast
    assert judge_spot(faint, target, spec, lim, 0.35, ambient, ambient)[0] in ("low_contrast", "no_spot")
    assert judge_spot(faint, target, spec, lim, 0.35, ambient, ambient, exposure=e)[0] == "ok"
    # below min_contrast even exposed: no_spot when the peak over the noise's growth is under the fraction
    dim = spot(100.0 * 0.5 * lim.min_contrast / (e * peak_nominal))  # exposed peak 0.5 · min_contrast
    exposed_peak = e * gain * peak_wm2(dim)
    assert exposed_peak == pytest.approx(0.5 * lim.min_contrast)
    assert exposed_peak / noise_scale(e, spec.read_noise_share) < 0.5 * lim.min_contrast
    assert judge_spot(dim, target, spec, lim, 0.35, ambient, ambient, exposure=e)[0] == "no_spot"
