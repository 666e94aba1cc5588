"""report: what a crew reads — the banner says what to act on, every error measure has one name and
its own limit line, clause 8.2 says which wind bins have no data, figure text is readable and
times show the site's clock beside UTC.

Campaign databases are written through the real Store on a real SQLite file (helpers of
test_report_build); expectations are computed here from the construction, not from the report's code.
"""

from __future__ import annotations

import datetime as dt
import json
import re
from pathlib import Path
from zoneinfo import ZoneInfo

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.text import Text  # noqa: E402

from helicalib.store import Store  # noqa: E402
from test_report_build import CFG, FIELD, IDS, T0, _obs, check_links, frames  # noqa: E402


def make(tmp: Path, *, not_accepted=(), clipped=2, winds=(3.5, 4.2), fault=None, finish=True,
         name="crew.db", off_tracking=()) -> Path:
    """Four heliostats, two visits each (placement errors 1.0 and 0.8 mrad); the first ``clipped``
    heliostats' first visit starts with a clipped frame the loop recovers from. Verdicts accepted
    unless in ``not_accepted`` (then an RMS reason)."""
    db = tmp / name
    store = Store.open(db, durable=False)
    cid = store.start_campaign(name="crew", mode="simulate", started_s=T0,
                               heliostats=[(h, CFG.heliostat_index(h), CFG.heliostat(h).target) for h in IDS],
                               config_path=str(FIELD), settings={})
    for k, hid in enumerate(IDS):
        tid = CFG.heliostat(hid).target
        before, after, _ = frames(tid)
        for j, (hour, err) in enumerate(((8.0, 1.0), (11.0, 0.8))):
            t = T0 + (hour + 0.1 * k) * 3600.0
            vid = store.begin_visit(cid, hid, tid, t)
            it = 0
            if j == 0 and k < clipped:
                store.record_observation(_obs(cid, hid, tid, vid, 0, t + 30, valid=False, reason="clipped",
                                              wind=winds[j]), before_frame=before, after_frames=[after])
                it = 1
            store.record_observation(_obs(cid, hid, tid, vid, it, t + 60, err=err, wind=winds[j], spot=(686.0, 525.0)),
                                     before_frame=before, after_frames=[after])
            store.end_visit(vid, ended_s=t + 120, outcome="converged", reason="ok", iterations=it + 1,
                            first_error_mrad=err, final_error_mrad=err)
        bad = hid in not_accepted
        store.record_verdict(campaign_id=cid, heliostat_id=hid, time_s=T0 + 12 * 3600.0, accepted=not bad, n_points=5,
                             rms_mrad=1.4 if bad else 0.9, reasons=["RMS error 1.40 mrad > 1.2 mrad"] if bad else [])
    store.record_fit(campaign_id=cid, heliostat_id=IDS[0], time_s=T0 + 12 * 3600.0, model="error-model",
                     params={"pedestal_tilt_e_mrad": 0.2}, sigma={"pedestal_tilt_e_mrad": 0.05}, rms_mrad=0.6, n_points=4)
    if fault:
        store.record_event(campaign_id=cid, time_s=T0 + 9 * 3600.0, kind="fault", reason=fault)
    for t, kind, hid in off_tracking:  # what the runner records when a return to tracking fails / is confirmed
        store.record_event(campaign_id=cid, time_s=t, kind=kind, heliostat_id=hid, reason=f"{hid}: {kind}")
    if finish:
        store.finish_campaign(cid, T0 + 20 * 3600.0)
    store.close()
    return db


def build(db: Path, out: Path, **kw):
    from helicalib.report.build import build_report

    index = build_report(db, out, frames=False, **kw)
    return index, json.loads((index.parent / "report.json").read_text())


@pytest.fixture(scope="module")
def calm(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("calm")
    return build(make(tmp), tmp / "out")


# ------------------------------------------------------------------------------------ banner
def test_all_accepted_with_recovered_clipped_frames_is_nothing_to_act_on(calm):
    index, rep = calm
    st = rep["status"]
    assert rep["summary"]["invalid_by_reason"] == {"clipped": 2} and rep["summary"]["accepted"] == len(IDS)
    assert st["level"] == "ok" and not st["partly_failed"] and st["actions"] == []
    info = " ".join(st["information"])
    assert "2 clipped" in info and "still gave a valid point" in info
    page = index.read_text()
    banner = page.split('id="banner"')[1].split("</div>")[0]
    assert 'class="banner ok"' in page and "Nothing to act on" in banner and "clipped" in banner
    assert "Partly failed" not in page and "To act on" not in banner


def test_unaccepted_heliostat_is_named_in_the_banner(tmp_path):
    index, rep = build(make(tmp_path, not_accepted=("H0003",)), tmp_path / "out")
    st = rep["status"]
    assert st["level"] == "action" and st["not_accepted"] == ["H0003"]
    sentence = next(a for a in st["actions"] if "not accepted" in a)
    assert "H0003" in sentence and "RMS error 1.40 mrad" in sentence and "H0001" not in sentence
    banner = index.read_text().split('id="banner"')[1].split("</div>")[0]
    assert "To act on" in banner and "H0003" in banner and 'banner action' in index.read_text()


def test_off_tracking_fault_and_unfinished_campaign_are_actions(tmp_path):
    # H0002 left off tracking; H0003 was too, but the plant confirmed it back later
    stranded = ((T0 + 9 * 3600.0, "off_tracking", "H0002"), (T0 + 9 * 3600.0, "off_tracking", "H0003"),
                (T0 + 10 * 3600.0, "back_to_tracking", "H0003"))
    _index, rep = build(make(tmp_path, fault="H0002: weather: timeout", finish=False, off_tracking=stranded),
                        tmp_path / "o")
    st = rep["status"]
    assert st["level"] == "action" and st["off_tracking"] == ["H0002"]
    text = " ".join(st["actions"])
    assert "not confirmed back to tracking" in text and "1 fault event" in text and "unfinished" in text


# ------------------------------------------------------------------------------------ measures
OLD_LABELS = ("<th>RMS [mrad]</th>", "present error", "RMS of valid", "tracking error [mrad]")


def _resolve(rep: dict, path: str) -> bool:
    """Whether a glossary ``json_keys`` path (``a.b[].c``) leads to a value in report.json."""
    nodes = [rep]
    for part in path.split(" ")[0].split("."):
        key, many = part.removesuffix("[]"), part.endswith("[]")
        nxt = []
        for node in nodes:
            if isinstance(node, dict) and key in node:
                nxt += node[key] if many else [node[key]]
        nodes = [n for n in nxt if n is not None]
        if not nodes:
            return False
    return True


def test_every_error_measure_is_named_once_with_a_glossary(calm):
    from helicalib.report.measures import MEASURES

    index, rep = calm
    page = index.read_text()
    assert 'id="glossary"' in page
    gloss = {g["key"]: g for g in rep["glossary"]}
    assert set(gloss) == set(MEASURES)
    for key, m in MEASURES.items():
        assert f"<dt id=\"m-{key}\">{m.name} [mrad]</dt>" in page
        for path in gloss[key]["json_keys"]:
            if not path.startswith("heliostats/"):
                assert _resolve(rep, path), f"glossary names {path}, which report.json lacks"
    assert str(CFG.acceptance.max_rms_mrad) in gloss["acceptance_error"]["limit"]
    assert f"{CFG.calibration.loop_threshold_mrad:g} mrad" in gloss["placement_error"]["limit"]
    head = page.split("<h2>Heliostats")[1].split("</thead>")[0]
    assert "acceptance error [mrad]" in head and "latest placement error [mrad]" in head
    sheet = (index.parent / rep["heliostats"][0]["href"]).read_text()
    for text in (page, sheet):
        for old in OLD_LABELS:
            assert old not in text
    for nm in ("acceptance error", "latest placement error", "placement-error RMS", "placement error by placement"):
        assert nm in sheet


def _hlines(ax, y: float) -> list:
    return [ln for ln in ax.get_lines() if isinstance(ln, Line2D) and len(ln.get_ydata()) >= 2
            and np.allclose(np.asarray(ln.get_ydata(), float), y)]


def test_limit_lines_are_drawn_only_over_their_own_measure(calm):
    from helicalib.report.sheet_plots import SheetPlotter

    _index, rep = calm
    acc, loop = CFG.acceptance.max_rms_mrad, CFG.calibration.loop_threshold_mrad
    assert acc != loop
    with SheetPlotter(rep["acceptance"], loop, (T0, T0 + 20 * 3600.0), 5.0, 2) as sp:
        with_acc = [ax for ax in sp.axes if _hlines(ax, acc)]
        with_loop = [ax for ax in sp.axes if _hlines(ax, loop)]
        assert with_acc and with_loop
        assert all(ax.get_ylabel() == "acceptance error [mrad]" for ax in with_acc)
        assert all(ax.get_ylabel() == "placement error [mrad]" for ax in with_loop)
        labels = {ax.get_ylabel() for ax in sp.axes}
        assert labels == {"acceptance error [mrad]", "placement error [mrad]"}


def test_field_map_colours_by_acceptance_error_with_its_limit(calm):
    from helicalib.report.plots import figure_field_map

    _index, rep = calm
    fm = rep["field_map"]
    assert [r["acceptance_error_mrad"] for r in fm["heliostats"]] == [0.9] * len(IDS)
    fig = figure_field_map(fm)
    bars = [ax for ax in fig.axes if _hlines(ax, fm["acceptance_limit_mrad"])]
    assert len(bars) == 1 and bars[0].get_ylabel().startswith("acceptance error [mrad]")
    matplotlib.pyplot.close(fig)


# ------------------------------------------------------------------------------------ clause 8.2
def test_wind_bins_without_data_say_no_data_not_failure(calm):
    index, rep = calm
    winds = {3.5, 4.2}  # every first placement of the construction
    field = rep["tracking_test"]["field"]
    assert field["verdict"] == "incomplete"
    for b in field["bins"]:
        has = any(b["low_ms"] <= w <= b["high_ms"] for w in winds)
        assert (b["status"] != "no data") == has
        if not has:
            assert b["text"].endswith("no data at this wind (not a failure)")
    missing = [b["wind_ms"] for b in field["bins"] if not any(b["low_ms"] <= w <= b["high_ms"] for w in winds)]
    assert missing and field["missing_ms"] == missing
    assert all(f"{w:g} m/s" in field["summary"] for w in missing) and "not a failure" in field["summary"]
    page = index.read_text()
    section = page.split("Tracking accuracy, T/GRLM")[1].split("<h2>")[0]
    assert section.count("no data at this wind (not a failure)") == len(missing)
    row = page.split(f'>{IDS[0]}</a>')[1].split("</tr>")[0]
    assert "incomplete" not in row and all(f"{w:g} m/s no data" in row for w in missing) and "4 m/s met" in row
    sheet = (index.parent / rep["heliostats"][0]["href"]).read_text()
    assert sheet.count("no data at this wind (not a failure)") == len(missing)


# ------------------------------------------------------------------------------------ readability
def _texts(fig) -> list[Text]:
    fig.canvas.draw()
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def test_every_figure_text_is_at_least_10_pt_at_the_displayed_size(calm):
    from helicalib.report import plots
    from helicalib.report.sheet_plots import SheetPlotter
    from helicalib.geometry.sitetime import site_time

    _index, rep = calm
    site = site_time(CFG)
    figs = [plots.figure_field_map(rep["field_map"]), plots.figure_progress(rep["progress"], site),
            plots.figure_3(rep["tracking_test"])]
    figs += [plots.figure_pass_rate(rep["pass_rate"][k], n, 3.5) for n, k in ((6, "wind"), (7, "dni"), (8, "cleanliness"))]
    sp = SheetPlotter(rep["acceptance"], 3.5, (T0, T0 + 20 * 3600.0), 5.0, 2, site)
    figs.append(sp.fig)
    for fig in figs:
        width_px = fig.get_size_inches()[0] * fig.dpi
        assert width_px <= 1200  # the page's column: shown 1:1, never scaled down
        texts = _texts(fig)
        assert len(texts) > 5
        small = [(t.get_text(), t.get_fontsize()) for t in texts if t.get_fontsize() < 10.0]
        assert not small, small
        matplotlib.pyplot.close(fig)
    for png in (_index.parent / "plots").glob("*.png"):
        import cv2

        assert cv2.imread(str(png)).shape[1] <= 1200


# ------------------------------------------------------------------------------------ local time
def _solar(t_s: float) -> str:
    minutes = round(CFG.site.longitude_deg * 4.0)
    return dt.datetime.fromtimestamp(t_s + 60 * minutes, tz=dt.timezone.utc).strftime("%H:%M")


def test_local_time_beside_utc_in_tables_and_plots(calm, tmp_path):
    from helicalib.report import plots
    from helicalib.geometry.sitetime import site_time

    index, rep = calm
    page = index.read_text()
    start = T0
    utc = dt.datetime.fromtimestamp(start, tz=dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    assert re.search(re.escape(utc) + r' <span class="local">\((\d\d-\d\d )?' + _solar(start) + " solar time\\)", page)
    assert "local mean solar time" in rep["time_zone"]["description"]
    sheet = (index.parent / rep["heliostats"][0]["href"]).read_text()
    assert "solar time)" in sheet.split("<h2>Observations (")[1]
    fig = plots.figure_progress(rep["progress"], site_time(CFG))
    offset = round(CFG.site.longitude_deg * 4.0)
    every = fig.axes + [c for ax in fig.axes for c in ax.child_axes]  # secondary axes are children
    tops = [ax.get_xlabel() for ax in every if "solar" in ax.get_xlabel()]
    assert tops == [f"local solar time (UTC+{offset // 60:02d}:{offset % 60:02d})"]
    matplotlib.pyplot.close(fig)
    # a zone given to the report: the plant's clock
    db = make(tmp_path)
    index2, rep2 = build(db, tmp_path / "tz", timezone="Asia/Shanghai")
    shanghai = dt.datetime.fromtimestamp(start, tz=ZoneInfo("Asia/Shanghai")).strftime("%H:%M")
    assert f"{shanghai} Asia/Shanghai)" in index2.read_text() and rep2["time_zone"]["source"] == "report option"
    check_links(index2)


def test_bad_time_zone_is_one_clear_error(tmp_path):
    from helicalib.cli import main
    from helicalib.errors import ConfigError
    from helicalib.geometry.sitetime import parse_zone

    assert parse_zone("+08:00")[0].utcoffset(None) == dt.timedelta(hours=8)
    assert parse_zone("UTC-3:30")[0].utcoffset(None) == -dt.timedelta(hours=3, minutes=30)
    with pytest.raises(ConfigError, match="Mars/Olympus"):
        parse_zone("Mars/Olympus")
    db = make(tmp_path)
    assert main(["report", str(db), "--out", str(tmp_path / "x"), "--no-frames", "--timezone", "Mars/Olympus"]) == 1
