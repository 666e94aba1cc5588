"""The ``spot`` and ``accuracy`` commands on real files (rendered PNG frames, CSV series)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import yaml

from helicalib.cli import main
from helicalib.config import load_field_config
from helicalib.vision.frames import encode_png, write_png
from helicalib.sim.render import Spot, pose_from_camera, render_frame


@pytest.fixture(scope="module")
def scene(tmp_path_factory, demo_field_path):
    DEMO_FIELD = demo_field_path
    field = load_field_config(DEMO_FIELD)
    target = field.target("T1")
    pose = pose_from_camera(field.cameras_for("T1")[0], target)
    d = tmp_path_factory.mktemp("cli")
    write_png(d / "before.png", render_frame(target, pose, rng=1))
    spot = Spot(center_m=(0.8, -0.6), size_m=(0.8, 0.7), peak=70)
    write_png(d / "after.png", render_frame(target, pose, [spot], rng=2))
    (d / "target.yaml").write_text(yaml.safe_dump({"targets": [target.model_dump(mode="json")]}))
    return d, DEMO_FIELD, spot


def test_spot_json_with_target_file_and_overlay(scene, capsys):
    d, _, spot = scene
    rc = main(["spot", str(d / "before.png"), str(d / "after.png"), "--target", str(d / "target.yaml"), "--json",
               "--overlay", str(d / "ov.png")])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["valid"] and out["reason"] == "ok"
    assert np.allclose(out["offset_m"], spot.center_m, atol=0.006)
    for key in ("spot_center_px", "target_center_px", "spot_area_px", "threshold", "jitter_m"):
        assert key in out
    assert (d / "ov.png").read_bytes().startswith(b"\x89PNG")


def test_spot_with_field_and_target_id_all_methods(scene, capsys):
    d, field, spot = scene
    for method in ("grlm", "grlm-centroid", "centroid"):
        rc = main(["spot", str(d / "before.png"), str(d / "after.png"), "--field", str(field), "--target-id", "T1",
                   "--method", method, "--json"])
        out = json.loads(capsys.readouterr().out)
        assert rc == 0 and out["method"] == method
        assert np.allclose(out["offset_m"], spot.center_m, atol=0.02)


def test_spot_broken_frame_is_an_invalid_result(scene, tmp_path, capsys):
    d, _, _ = scene
    (tmp_path / "cut.png").write_bytes((d / "after.png").read_bytes()[:500])
    rc = main(["spot", str(d / "before.png"), str(tmp_path / "cut.png"), "--target", str(d / "target.yaml")])
    out = capsys.readouterr().out
    assert rc == 3 and "bad_frame" in out and "truncated" in out


def test_spot_user_errors_are_one_line(scene, capsys, tmp_path):
    d, field, _ = scene
    assert main(["spot", str(d / "before.png"), str(d / "after.png")]) == 1
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({"id": "X", "center_enu_m": [0, 0], "normal_enu": [0, 1, 0],
                                                       "size_m": [1, 1]}))
    assert main(["spot", str(d / "before.png"), str(d / "after.png"), "--target", str(tmp_path / "bad.yaml")]) == 1
    err = capsys.readouterr().err
    assert "center_enu_m" in err and "Traceback" not in err


def test_accuracy_from_uv_and_frames(scene, tmp_path, capsys):
    d, field_path, spot = scene
    field = load_field_config(field_path)
    h = field.heliostat("H0008")  # aims at T1
    target = field.target("T1")
    L = np.linalg.norm(np.asarray(target.center_enu_m) - np.asarray(h.position_enu_m))
    rows = []
    # 4 m/s: 100 rows within, then 8 m/s: 7 of 10 within, 11 m/s: 4 of 10 within  → pass
    for i in range(100):
        rows.append({"time": f"2026-06-01T10:{i // 60:02d}:{i % 60:02d}+08:00", "heliostat": "H0008", "wind_ms": 4.0, "u_m": 2.0e-3 * L, "v_m": 0.0})
    for i in range(10):
        rows.append({"time": f"2026-06-02T10:00:{i:02d}+08:00", "heliostat": "H0008", "wind_ms": 8.3,
                     "u_m": (3.0e-3 if i < 7 else 5.0e-3) * L, "v_m": 0.0})
    for i in range(10):
        rows.append({"time": f"2026-06-03T10:00:{i:02d}+08:00", "heliostat": "H0008", "wind_ms": 10.6,
                     "u_m": 0.0, "v_m": (3.0e-3 if i < 4 else 6.0e-3) * L})
    series = tmp_path / "series.csv"
    with series.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["time", "heliostat", "wind_ms", "u_m", "v_m"])
        w.writeheader()
        w.writerows(rows)
    rc = main(["accuracy", str(series), "--field", str(field_path), "--json", "--plot", str(tmp_path / "f3.png"),
               "--summary", str(tmp_path / "s.json"), "--per-frame", str(tmp_path / "pf.csv")])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["verdict"] == "pass"
    r = out["heliostats"]["H0008"]
    assert [b["n"] for b in r["bins"]] == [100, 10, 10] and [b["within"] for b in r["bins"]] == [100, 7, 4]
    assert (tmp_path / "f3.png").read_bytes().startswith(b"\x89PNG")
    assert json.loads((tmp_path / "s.json").read_text())["verdict"] == "pass"
    per = list(csv.DictReader((tmp_path / "pf.csv").open()))
    assert float(per[0]["eta_mrad"]) == pytest.approx(2.0, rel=1e-9)  # formula (1): |X-T|/L

    # frame rows: one good pair and one broken after-frame
    (tmp_path / "broken.png").write_bytes(encode_png(np.zeros((10, 10), np.uint8))[:30])
    fr = tmp_path / "frames.csv"
    fr.write_text("time,heliostat,wind_ms,before,after\n"
                  f"2026-06-01T10:00:00+08:00,H0008,4.0,{d / 'before.png'},{d / 'after.png'}\n"
                  f"2026-06-01T10:01:00+08:00,H0008,4.2,{d / 'before.png'},{tmp_path / 'broken.png'}\n")
    rc = main(["accuracy", str(fr), "--field", str(field_path), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["valid_rows"] == 1 and out["invalid_reasons"] == {"bad_frame": 1}
    eta = out["heliostats"]["H0008"]["accuracy_rms_mrad"]
    assert eta == pytest.approx(1000 * np.hypot(*spot.center_m) / L, abs=0.1)
    assert out["verdict"] == "fail"  # 1 m off at ~106 m is ~9.5 mrad, the only row of the 4 m/s bin
