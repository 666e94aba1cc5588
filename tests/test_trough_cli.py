"""``helicalib trough`` end to end with real files, and the COLLECTOR/CAMERA YAML checks."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from helicalib.cli import main
from helicalib.errors import ConfigError
from helicalib.trough.config import load_camera, load_collector

FIELD_CONFIG = Path(__file__).resolve().parents[1] / "field_config"


@pytest.fixture()
def inputs(tmp_path):
    collector = yaml.safe_load((FIELD_CONFIG / "trough_collector.yaml").read_text())
    camera = yaml.safe_load((FIELD_CONFIG / "trough_camera.yaml").read_text())
    camera.update(image_size_px=[640, 480], pixel_pitch_um=11.0)  # binned, for speed
    c, k = tmp_path / "collector.yaml", tmp_path / "camera.yaml"
    c.write_text(yaml.safe_dump(collector))
    k.write_text(yaml.safe_dump(camera))
    return c, k


def test_example_inputs_are_the_papers_unit():
    c = load_collector(FIELD_CONFIG / "trough_collector.yaml")
    k = load_camera(FIELD_CONFIG / "trough_camera.yaml")
    assert (c.focal_length_mm, c.tube_radius_mm, c.aperture_mm, c.rows, c.columns) == (1710, 35, 5774, 4, 7)
    assert k.position_mm == (0, 831, 10000)
    assert k.pinhole().focal_length_px == pytest.approx(8.0 / 4.4e-3)
    bounds = c.row_bounds_mm()
    assert np.mean(bounds[1]) == pytest.approx(831, abs=1) and np.mean(bounds[0]) == pytest.approx(2263, abs=1)


def test_render_then_overlay_finds_the_tilted_facet(inputs, tmp_path, capsys):
    c, k = inputs
    photo = tmp_path / "photo.png"
    assert main(["trough", "render", "--collector", str(c), "--camera", str(k), "--tilt", "R2C3=3.5",
                 "--supersample", "2", "--out", str(photo)]) == 0
    img = cv2.imread(str(photo), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (480, 640)
    out = tmp_path / "out"
    assert main(["trough", "overlay", "--collector", str(c), "--camera", str(k), "--image", str(photo),
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "R2C3" in text and "adjust" in text
    result = json.loads((out / "overlay.json").read_text())
    assert result["measured"] is True
    by_id = {f["id"]: f for f in result["facets"]}
    assert by_id["R2C3"]["tilt"]["verdict"] == "adjust"
    assert by_id["R2C3"]["tilt"]["tilt_mrad"] == pytest.approx(3.5, abs=0.15)
    assert by_id["R2C3"]["tilt"]["direction"] == "upper edge towards the focal line"
    assert by_id["R2C4"]["tilt"]["verdict"] == "ok"
    assert "tilt" not in by_id["R1C4"] and by_id["R1C4"]["visible"] is False
    pic = cv2.imread(str(out / "overlay.png"))
    assert pic.shape == (480, 640, 3)
    # the overlay draws green theory lines over the grey photo
    assert np.any((pic[:, :, 1] > 150) & (pic[:, :, 0] < 60) & (pic[:, :, 2] < 60))


def test_overlay_without_photo_gives_theory_only(inputs, tmp_path):
    c, k = inputs
    out = tmp_path / "theory"
    assert main(["trough", "overlay", "--collector", str(c), "--camera", str(k), "--out", str(out)]) == 0
    result = json.loads((out / "overlay.json").read_text())
    assert result["measured"] is False
    r2 = [f for f in result["facets"] if f["visible"]]
    assert {f["row"] for f in r2} == {2} and len(r2) == 5
    b = r2[0]["theory"]["B_lower"]
    assert b["z_mm"] == pytest.approx(b["y_mm"] ** 2 / (4 * 1710), abs=1e-3)  # eq. (1)
    assert all("tilt" not in f for f in result["facets"])
    assert (out / "overlay.png").is_file()


def test_gauge_command(inputs, capsys):
    c, _ = inputs
    assert main(["trough", "gauge", "--collector", str(c), "--distance-mm", "10000"]) == 0
    d = float(capsys.readouterr().out.split("d = ")[1].split(" mm")[0])
    assert main(["trough", "gauge", "--collector", str(c), "--gauge-width-mm", f"{d}"]) == 0
    opc = float(capsys.readouterr().out.split("OPc = ")[1].split(" mm")[0])
    assert opc == pytest.approx(10000.0, abs=0.5)  # d printed to 1 µm; dOPc/dd ≈ -118


def test_errors_are_one_line(inputs, tmp_path, capsys):
    c, k = inputs
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**yaml.safe_load(c.read_text()), "focal_lenght_mm": 1700}))
    assert main(["trough", "overlay", "--collector", str(bad), "--camera", str(k), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.yaml" in err and "focal_lenght_mm: unknown key" in err
    assert main(["trough", "render", "--collector", str(c), "--camera", str(k), "--tilt", "R9C1=1",
                 "--out", str(tmp_path / "p.png")]) == 1
    assert "R9C1" in capsys.readouterr().err
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not a png")
    assert main(["trough", "overlay", "--collector", str(c), "--camera", str(k), "--image", str(junk),
                 "--out", str(tmp_path / "o")]) == 1
    assert "not a readable image" in capsys.readouterr().err


@pytest.mark.parametrize("change, message", [
    ({"row_edges_mm": [[50, 1612]]}, "row_edges_mm: expected 4 pairs"),
    ({"row_edges_mm": [[-2887, -1640], [-1612, -50], [50, 1612], [1640, 2887]]}, "listed from the top"),
    ({"row_edges_mm": [[1640, 3000], [50, 1612], [-1612, -50], [-2887, -1640]]}, "inside ±aperture_mm/2"),
    ({"tube_radius_mm": -1}, "tube_radius_mm"),
    ({"rows": "four"}, "rows"),
])
def test_collector_validation_names_the_key(tmp_path, change, message):
    data = {**yaml.safe_load((FIELD_CONFIG / "trough_collector.yaml").read_text()), **change}
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message) as info:
        load_collector(path)
    assert all(line.startswith(f"{path}: ") for line in info.value.problems)


def test_camera_validation(tmp_path):
    data = yaml.safe_load((FIELD_CONFIG / "trough_camera.yaml").read_text())
    path = tmp_path / "k.yaml"
    path.write_text(yaml.safe_dump({**data, "rotation_deg": [0, 45, 0]}))
    with pytest.raises(ConfigError, match="rotation_deg"):
        load_camera(path)
    path.write_text(yaml.safe_dump({k: v for k, v in data.items() if k != "position_mm"}))
    with pytest.raises(ConfigError, match="position_mm: missing required key"):
        load_camera(path)
    with pytest.raises(ConfigError, match="file not found"):
        load_camera(tmp_path / "none.yaml")
