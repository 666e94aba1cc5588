"""A sweep file's spots_per_board: beams taking turns on the boards in every run of the grid."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from helicalib.errors import ConfigError
from helicalib.sweep.spec import load_sweep

ROOT = Path(__file__).resolve().parents[1]
BASE = {"field": str(ROOT / "field_config" / "demo_north.yaml"), "days": 0.1, "seeds": [1, 2], "planners": ["gaps"]}


def _runs(tmp_path, **extra):
    path = tmp_path / f"s{len(list(tmp_path.iterdir()))}.yaml"
    path.write_text(yaml.safe_dump({**BASE, **extra}))
    return load_sweep(path).runs(tmp_path / "out")


def test_each_run_takes_the_sweep_s_spots_per_board_into_its_options_and_digest(tmp_path):
    plain, one, auto, three = (_runs(tmp_path), _runs(tmp_path, spots_per_board=1),
                               _runs(tmp_path, spots_per_board="auto"), _runs(tmp_path, spots_per_board=3))
    assert [r.spots_per_board for r in plain] == [1, 1] and [r.spots_per_board for r in auto] == ["auto", "auto"]
    assert [r.spots_per_board for r in three] == [3, 3]
    # one visit per board is the default: a sweep that says so keeps the digests of one that does not
    assert [r.digest for r in one] == [r.digest for r in plain]
    assert len({r.digest for r in plain + auto + three}) == 6
    assert [r.sim_seed for r in auto] == [r.sim_seed for r in plain]  # the same worlds, other planning


@pytest.mark.parametrize("bad", [0, -2, "many", 2.5, True])
def test_a_bad_spots_per_board_is_refused_in_one_line_naming_the_key(tmp_path, bad):
    with pytest.raises(ConfigError) as err:
        _runs(tmp_path, spots_per_board=bad)
    assert "spots_per_board" in str(err.value) and "\n" not in str(err.value)
