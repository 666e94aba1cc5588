"""Progress of long commands when stderr is not a terminal (make, CI): plain lines, rate-limited."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest

from helicalib.cli import main
from helicalib.commands import _progress
from helicalib.commands._progress import ProgressReporter, format_elapsed, timed_step
from helicalib.sim.field import generate_field

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_plain_lines_are_rate_limited_and_closed_with_the_latest_state():
    out, clock = io.StringIO(), FakeClock()
    calls = []

    def text(i):
        def describe():
            calls.append(i)
            return f"step {i}"
        return describe

    with ProgressReporter("job", 100.0, interval_s=10.0, stream=out, clock=clock, terminal=False) as bar:
        for i in range(36):                       # one update per second of real time
            bar.update(i, text(i))
            clock.t += 1.0
    lines = out.getvalue().splitlines()
    assert lines[:4] == ["job: step 0, elapsed 0 s", "job: step 10, elapsed 10 s", "job: step 20, elapsed 20 s",
                         "job: step 30, elapsed 30 s"]
    assert lines[4:] == ["job: done, step 35, elapsed 36 s"]
    assert calls == [0, 10, 20, 30, 35]           # a description is only worked out when it is shown


def test_a_failed_run_says_so_and_the_terminal_case_draws_no_plain_lines():
    out, clock = io.StringIO(), FakeClock()
    with pytest.raises(RuntimeError):
        with ProgressReporter("job", None, stream=out, clock=clock, terminal=False) as bar:
            bar.update(1, "half")
            clock.t += 3
            raise RuntimeError("boom")
    assert out.getvalue().splitlines()[-1] == "job: stopped, half, elapsed 3 s"
    tty = io.StringIO()
    with ProgressReporter("job", 10.0, stream=tty, clock=clock, terminal=True, interval_s=0.0) as bar:
        for i in range(10):
            bar.update(i + 1, f"step {i}")
    assert "job: step" not in tty.getvalue()      # the bar, not the log lines


def test_timed_step_brackets_a_step():
    out, clock = io.StringIO(), FakeClock()
    with timed_step("demo", "building the report", stream=out, clock=clock):
        clock.t += 75
    assert out.getvalue().splitlines() == ["demo: building the report ...", "demo: building the report done in 1 min 15 s"]
    assert format_elapsed(3725) == "1 h 02 min"


def test_simulate_prints_progress_lines_when_stderr_is_not_a_terminal(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(_progress, "DEFAULT_INTERVAL_S", 0.2)     # the run lasts seconds: several lines
    out = tmp_path / "run"
    rc = main(["simulate", str(FIELD), "--days", "0.03", "--start", "2026-06-01T02:00:00Z", "--heliostats",
               "H0007,H0008", "--out", str(out), "--json", "--report"])
    assert rc == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    lines = captured.err.splitlines()
    pat = re.compile(r"^simulate: day (\d+\.\d+) of 0\.03, (\d+) visits, (\d+) accepted, elapsed (\d+) s$")
    progress = [pat.match(ln) for ln in lines if ln.startswith("simulate: day")]
    assert len(progress) >= 2 and all(progress), lines
    days = [float(m.group(1)) for m in progress]
    visits = [int(m.group(2)) for m in progress]
    assert days == sorted(days) and days[-1] > days[0] and visits == sorted(visits)
    done = [ln for ln in lines if ln.startswith("simulate: done, ")]
    assert len(done) == 1
    m = re.match(r"simulate: done, day [\d.]+ of 0\.03, (\d+) visits, (\d+) accepted", done[0])
    assert m and int(m.group(1)) == summary["visits"] and int(m.group(2)) == summary["accepted"]
    report_dir = out / "report"
    assert f"simulate: building the report in {report_dir} ..." in lines
    assert any(ln.startswith(f"simulate: building the report in {report_dir} done in ") for ln in lines)
    assert lines.index(done[0]) < lines.index(f"simulate: building the report in {report_dir} ...")


def test_generate_field_reports_growing_progress():
    seen = []
    data, rows = generate_field(30, 40.0, 94.0, targets=2, step_days=61.0, step_min=120.0,
                                progress=lambda done, total, candidates: seen.append((done, total, candidates)))
    assert len(rows) == 30 and len(seen) >= 2
    done = [d for d, _, _ in seen]
    assert done == sorted(done) and len(set(done)) == len(done)         # strictly increasing
    assert all(0 < d <= t for d, t, _ in seen) and all(c >= 30 for _, _, c in seen)
    assert seen[-1][0] == seen[-1][1]                                     # the last check closes the count


def test_sim_field_command_prints_progress(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(_progress, "DEFAULT_INTERVAL_S", 0.0)
    assert main(["sim-field", "--n", "20", "--site=40,94", "--targets", "2", "--out", str(tmp_path / "f.yaml")]) == 0
    err = capsys.readouterr().err.splitlines()
    done = [int(m.group(1)) for ln in err if (m := re.match(r"sim-field: year's stroke checks \d+ % \((\d+) of", ln))]
    assert len(done) >= 2 and done == sorted(done) and done[-1] > done[0]
    assert err[-1].startswith("sim-field: done, year's stroke checks 100 %")
