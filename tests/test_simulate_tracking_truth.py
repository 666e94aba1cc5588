"""The summary's true plant tracking error: the corrections held over each refresh period."""

from __future__ import annotations

import numpy as np

from helicalib.campaign.verdict import TRACKING_REFRESH_S, tracking_corrections
from helicalib.app.sim_figures import plant_tracking_truth
from helicalib.app.simulated import default_start_s
from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.heliostat import tracking_approach
from helicalib.geometry.sun import SunTable
from helicalib.sim.evaluate import TRACKING_LEAD_S
from helicalib.sim.plant import SimulatedPlant


def _reference(cfg, truth, params, rows, t0_s, t1_s, table, step_s=300.0):
    """plant_tracking_truth as written first: the corrections computed again at every step."""
    nominal = truth.nominal
    calibrated = nominal.with_params(params)
    aim = np.asarray(cfg.tower.receiver_aim_enu_m, dtype=float)
    errs = []
    for t in np.arange(t0_s, t1_s, step_s):
        sun = table.vector_enu(t)
        if np.degrees(np.arcsin(sun[2])) < cfg.acceptance.low_band_deg[0]:
            continue
        t_ref = t0_s + np.floor((t - t0_s) / TRACKING_REFRESH_S) * TRACKING_REFRESH_S + TRACKING_REFRESH_S / 2
        corr = np.nan_to_num(tracking_corrections(cfg, nominal, calibrated, table.vector_enu(t_ref),
                                                  table.vector_enu(t_ref + TRACKING_LEAD_S)))
        nom = nominal.strokes_for_aim(sun, aim)
        if not np.all(nom.in_range[rows]):
            continue
        approach = tracking_approach(nom.strokes_mm,
                                     nominal.strokes_for_aim(table.vector_enu(t + TRACKING_LEAD_S), aim).strokes_mm)
        beam = truth.beam(np.where(nom.in_range[:, None], nom.strokes_mm + corr, 0.0), sun, t, approach=approach,
                          jitter=False)
        errs.append(1000.0 * optics.angle_between_rad(beam.direction_enu, optics.unit(aim - beam.origin_enu))[rows])
    flat = np.concatenate(errs)
    return float(np.sqrt(np.mean(flat**2))), float(np.percentile(flat, 95))


def test_plant_tracking_truth_holds_each_refresh_periods_corrections(demo_field_path):
    cfg = load_field_config(demo_field_path)
    t0 = default_start_s(cfg) + 4 * 3600.0
    plant = SimulatedPlant(cfg, start_s=t0)
    params = np.random.default_rng(5).normal(0.0, 0.5, (plant.n, em.P)) * em.prior_sigma()
    rows = list(range(0, plant.n, 3))
    table = SunTable(cfg.site)
    got = plant_tracking_truth(cfg, plant.truth, params, rows, t0, t0 + 6 * 3600.0, table)
    want = _reference(cfg, plant.truth, params, rows, t0, t0 + 6 * 3600.0, table)
    assert (got["rms_mrad"], got["p95_mrad"]) == want
    assert got["rms_mrad"] > 0.1  # corrected, but not perfectly: the figure means something
