"""Sweep statistics and large grids: intervals keep each figure's scale (an RMS is never negative, a
share stays in [0, 1]) and hold the true mean about 95 % of the time; a cell that accepted nothing
says so; a grid beyond the limit is refused in one line; a large grid shows progress while it is
laid out; ``sweep --help`` prints what it means."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats

from helicalib.cli import main
from helicalib.sweep import results
from helicalib.sweep.results import mean_interval

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"


def _write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


# ------------------------------------------------------------------------------ intervals
def test_an_rms_interval_is_never_negative():
    rms = [0.2, 3.0, 0.4]                               # three seeds far apart, as in a sweep of few runs
    x = np.array(rms)
    n = len(rms)
    half = stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / math.sqrt(n)
    assert x.mean() - half < 0                          # what the plain t-interval said
    got = mean_interval(rms, "positive")
    y = np.log(x)
    v = y.var(ddof=1)
    h = stats.t.ppf(0.975, n - 1) * math.sqrt(v / n + v * v / (2 * (n - 1)))
    assert got["ci95"] == pytest.approx([math.exp(y.mean() + v / 2 - h), math.exp(y.mean() + v / 2 + h)])
    assert 0 < got["ci95"][0] < got["mean"] < got["ci95"][1]
    assert got["interval"] == "log-t" and got["mean"] == pytest.approx(1.2)


def test_two_seeds_get_the_t_interval_cut_at_0_and_nothing_overflows():
    """With two values the logarithms' variance has one degree of freedom: the log interval spans
    dozens of orders of magnitude ([0.05, 3.0] gave [6e-34, 1e36]), or overflows a float."""
    got = mean_interval([0.05, 3.0], "positive")
    half = stats.t.ppf(0.975, 1) * np.std([0.05, 3.0], ddof=1) / math.sqrt(2)
    assert got["interval"] == "t, cut at 0" and got["ci95"] == pytest.approx([0.0, 1.525 + half])
    wide = mean_interval([1e-300, 1.0, 1e-300], "positive")  # three seeds, but exp() would overflow
    assert wide["interval"] == "t, cut at 0" and all(math.isfinite(v) for v in wide["ci95"])


def test_a_share_interval_stays_between_0_and_1():
    got = mean_interval([0.9, 1.0, 1.0], "share")
    assert got["ci95"][1] == 1.0 and 0 <= got["ci95"][0] < 0.9
    assert mean_interval([0.0, 0.05], "share")["ci95"][0] == 0.0


def test_a_zero_among_positive_values_cuts_the_t_interval_at_0():
    got = mean_interval([0.0, 0.1, 2.0], "positive")
    assert got["ci95"][0] == 0.0 and got["interval"] == "t, cut at 0"
    assert got["ci95"][1] == pytest.approx(0.7 + stats.t.ppf(0.975, 2) * np.std([0, 0.1, 2.0], ddof=1) / math.sqrt(3))


@pytest.mark.parametrize("n", [3, 5])
def test_the_log_interval_holds_the_true_mean_95_percent_of_the_time(n):
    """Log-normal figures (sigma 0.5): 2000 draws of n seeds, the interval holds exp(sigma^2/2) in
    93-97 % of them (binomial sd 0.5 %)."""
    rng = np.random.default_rng(7)
    sigma, true = 0.5, math.exp(0.5 ** 2 / 2)
    held = 0
    for _ in range(2000):
        low, high = mean_interval(rng.lognormal(0.0, sigma, n), "positive")["ci95"]
        held += low <= true <= high
    assert 0.93 <= held / 2000 <= 0.97


def _row(cell: str, seed: int, accepted: int, rms_accepted):
    return {"cell": cell, "scenario": "default", "planner": "gaps", "start": "", "status": "ok", "seed": seed,
            "accepted": accepted, "acceptance_rate": accepted / 4, "days_to_95": None,
            "true_sky_rms_accepted_mrad": rms_accepted, "true_sky_rms_mrad": 1.0 + seed / 10,
            "visits_per_board_hour": 2.0 + seed}


def test_a_cell_that_accepted_nothing_says_so():
    rows = [_row("none", 1, 0, None), _row("none", 2, 0, None), _row("some", 1, 0, None), _row("some", 2, 3, 0.8)]
    cells = {c["cell"]: c for c in results.cell_statistics(rows)}
    assert cells["none"]["note"] == "no heliostat accepted in any seed"
    assert cells["none"]["figures"]["true_sky_rms_accepted_mrad"]["n"] == 0
    assert cells["some"]["note"] is None and cells["some"]["figures"]["true_sky_rms_accepted_mrad"]["n"] == 1
    lines = results.format_cells(list(cells.values()))
    assert "no heliostat accepted in any seed" in next(ln for ln in lines if ln.startswith("none"))
    assert "no heliostat accepted" not in next(ln for ln in lines if ln.startswith("some"))


def test_sweep_help_says_95_percent_once(capsys):
    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    out = capsys.readouterr().out
    assert "%%" not in out and "95 %" in " ".join(out.split())


# ------------------------------------------------------------------------------ large grids
def test_a_seed_given_twice_is_named_by_its_place(tmp_path, capsys):
    seeds = list(range(5000)) + [17]
    file = _write(tmp_path / "dup.yaml", {"field": str(FIELD), "days": 0.1, "seeds": seeds, "planners": ["gaps"]})
    assert main(["sweep", str(file), "--out", str(tmp_path / "o")]) == 1
    assert capsys.readouterr().err == f"helicalib sweep: error: {file}: seeds: [5000] 17 is given twice\n"


def test_a_grid_beyond_the_limit_is_refused_in_one_line(tmp_path, capsys):
    from helicalib.sweep.spec import MAX_RUNS

    starts = [f"2026-06-01T{h:02d}:{m:02d}:00+06:18" for h in range(24) for m in range(0, 60, 10)][:101]
    file = _write(tmp_path / "big.yaml", {"field": str(FIELD), "days": 0.1, "seeds": list(range(1000)),
                                          "planners": ["gaps"], "starts": starts})
    assert 1000 * 101 > MAX_RUNS
    assert main(["sweep", str(file), "--out", str(tmp_path / "o")]) == 1
    assert capsys.readouterr().err == (f"helicalib sweep: error: {file}: seeds: 1000 seeds x 101 cells = 101000 runs; "
                                       f"a sweep has at most {MAX_RUNS} runs (split it into several sweeps)\n")
    assert not (tmp_path / "o").exists()


def test_a_large_grid_shows_progress_while_it_is_laid_out(tmp_path, capsys):
    from helicalib.commands.sweep import _lay_out
    from helicalib.sweep.spec import PROGRESS_EVERY, load_sweep

    file = _write(tmp_path / "s.yaml", {"field": str(FIELD), "days": 0.1, "seeds": list(range(PROGRESS_EVERY)),
                                        "planners": ["gaps", "round-robin"]})
    sweep = load_sweep(file)
    runs = _lay_out(sweep, tmp_path / "o", quiet=False)
    assert len(runs) == 2 * PROGRESS_EVERY
    err = capsys.readouterr().err
    assert f"sweep: laying out runs: {PROGRESS_EVERY} of {2 * PROGRESS_EVERY}" in err
    assert "sweep: done" in err
    assert runs == sweep.runs(tmp_path / "o")           # the same runs as without progress
