"""``sim-field``: a generated field loads and every heliostat reaches its target and the receiver all year."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from helicalib.config import load_field_config
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_at_site, to_unix_seconds
from helicalib.sim.field import radial_staggered


def test_radial_staggered_rings_keep_spacing():
    pts = radial_staggered(300, 50.0, 8.0)
    assert len(pts) >= 300 and np.all(pts[:, 1] > 0)           # pole side (north) only
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() > 0.85 * 8.0 * 0.866                        # no two mirrors collide


def test_sim_field_cli_writes_feasible_field(tmp_path):
    out = tmp_path / "f.yaml"
    r = subprocess.run([sys.executable, "-m", "helicalib", "sim-field", "--n", "40", "--site=-30.5,-70.2,1500",
                        "--targets", "2", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    cfg = load_field_config(out)
    assert len(cfg.heliostats) == 40 and len(cfg.targets) == 2 and (tmp_path / "f.csv").is_file()
    assert np.all(cfg.heliostat_positions_enu_m()[:, 1] < 0)   # southern site: field south of the tower
    # independent sampling (other days and minutes than the generator's): strokes stay in range
    t0 = float(to_unix_seconds("2026-01-03T00:00:00Z"))
    times = t0 + (np.arange(0, 365, 11)[:, None] * 86400 + np.arange(0, 86400, 1700)[None, :]).ravel()
    sun = sun_at_site(cfg.site, times)
    vecs = np.asarray(sun.vector_enu)[sun.elevation_deg >= 5.0]
    model = HeliostatModel.from_config(cfg)
    aims = np.array([cfg.target(h.target).center_enu_m for h in cfg.heliostats])
    rec = np.array(cfg.tower.receiver_aim_enu_m)
    for s in vecs:
        assert model.strokes_for_aim(s, aims).in_range.all()
        assert model.strokes_for_aim(s, rec).in_range.all()
