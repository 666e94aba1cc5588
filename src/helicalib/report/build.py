"""Build the campaign report: ``index.html``, ``report.json``, PNG plots and one page per heliostat.

>>> from helicalib.report.build import build_report
>>> index = build_report("demo_out/helicalib.db", "demo_out/report")

Layout of ``out_dir``::

    index.html            campaign page (banner, summary, maps, progress, pass rates, T/GRLM, table)
    report.json           every figure of the pages (docs/report.md lists the keys)
    plots/*.png           campaign plots
    heliostats/<id>.html  one sheet per heliostat, linked from the sortable table
    heliostats/<id>.png   its observation plots; <id>_frames.png its latest frames; <id>.json its figures
"""

from __future__ import annotations

import datetime as _dt
import json
import time
from pathlib import Path

from helicalib.report import figures as F
from helicalib.report import html, plots
from helicalib.report.data import CampaignData, load_campaign
from helicalib.report.grlm import spec_of, tracking_test
from helicalib.report.measures import glossary
from helicalib.report.prediction import year_predictions
from helicalib.report.sheets import acceptance_spans, heliostat_sheet
from helicalib.geometry.sitetime import SiteTime, site_time


def _campaign_info(data: CampaignData) -> dict | None:
    c = data.campaign
    if c is None:
        return None
    field = str(data.cfg.source) if data.cfg is not None and data.cfg.source is not None else (c.config_path or None)
    return {"id": c.id, "name": c.name, "mode": c.mode, "status": c.status, "started_s": c.started_s,
            "ended_s": c.ended_s, "started_utc": F.iso(c.started_s), "ended_utc": F.iso(c.ended_s),
            "field_config": field, "config_note": data.config_note, "settings": c.settings}


def _file_names(ids: list[str]) -> dict[str, str]:
    """A distinct, file-safe stem per heliostat id."""
    from helicalib.store.frames import safe_name

    out, used = {}, set()
    for hid in ids:
        stem, k = safe_name(hid), 1
        while stem.lower() in used:
            stem, k = f"{safe_name(hid)}-{k}", k + 1
        used.add(stem.lower())
        out[hid] = stem
    return out


def limits(data: CampaignData) -> dict:
    """The limits the glossary names: the field config's, else the paper's values."""
    cfg = data.cfg
    return {"max_rms_mrad": float(cfg.acceptance.max_rms_mrad) if cfg is not None else F.DEFAULT_MAX_RMS_MRAD,
            "min_points": int(cfg.acceptance.min_points) if cfg is not None else 5,
            "loop_threshold_mrad": F.loop_threshold_mrad(data),
            "grlm_threshold_mrad": float(spec_of(cfg)["threshold_mrad"])}


def compute(data: CampaignData, site: SiteTime | None = None) -> dict:
    """Every campaign-level figure of the report (no per-heliostat sheet), as one JSON-ready dict."""
    from helicalib import __version__

    visits = F.visit_table(data)
    summ = F.summary(data, visits)
    site = site if site is not None else site_time(data.cfg)
    return {
        "schema": "helicalib-report/1",
        "helicalib": __version__,
        "generated_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
        "database": str(data.db_path),
        "campaign": _campaign_info(data),
        "status": F.banner(data, summ, visits),
        "summary": summ,
        "field_map": F.field_map(data),
        "progress": F.progress(data, visits),
        "pass_rate": F.pass_rates(data, visits),
        "tracking_test": tracking_test(data.observations, data.cfg),
        "acceptance": acceptance_spans(data),
        "washing": F.washing(data),
        "year_prediction": year_predictions(data),
        "events": F.events_log(data),
        "glossary": glossary(limits(data)),
        "limits": limits(data),
        "time_zone": site.to_json(),
    }


def build_report(db_path, out_dir, campaign_id: int | None = None, *, field_config=None, images_dir=None,
                 frames: bool = True, jobs: int | None = None, timezone: str | None = None) -> Path:
    """Write the report of one campaign (default: the newest) into ``out_dir``; returns ``index.html``.

    Parameters
    ----------
    db_path : str or Path
        The campaign database.
    out_dir : str or Path
        Output folder (created).
    campaign_id : int, optional
        Campaign to report (default the newest in the database).
    field_config : str or Path, optional
        Field config to use instead of the one the campaign recorded.
    images_dir : str or Path, optional
        Frames directory when not ``images`` beside the database.
    frames : bool
        Draw each heliostat's latest before/after frames (the slowest part on big fields).
    jobs : int, optional
        Processes drawing the heliostat sheets (default: the CPU count, at most 4; 1 = serial).
    timezone : str, optional
        The site's clock shown beside UTC: an IANA zone name or an offset such as ``+08:00``
        (default: the field config's, else local mean solar time from the site's longitude).
    """
    t_start = time.perf_counter()
    out = Path(out_dir)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    (out / "heliostats").mkdir(parents=True, exist_ok=True)
    data = load_campaign(db_path, campaign_id, field_config, images_dir)
    site = site_time(data.cfg, timezone)
    rep = compute(data, site)
    t_figures = time.perf_counter()

    images = {"field_map": plots.plot_field_map(rep["field_map"], out / "plots" / "field_map.png"),
              "progress": plots.plot_progress(rep["progress"], out / "plots" / "progress.png", site),
              "figure_3": plots.plot_figure_3(rep["tracking_test"], out / "plots" / "grlm_figure3.png")}
    for number, key in ((6, "wind"), (7, "dni"), (8, "cleanliness")):
        images[f"pass_{key}"] = plots.plot_pass_rate(rep["pass_rate"][key], out / "plots" / f"pass_rate_{key}.png",
                                                     number, rep["pass_rate"]["threshold_mrad"])
    images = {k: v.relative_to(out).as_posix() for k, v in images.items()}
    t_plots = time.perf_counter()

    rep["heliostats"] = _write_sheets(data, rep, out, frames, jobs, site)
    t_sheets = time.perf_counter()
    rep["timing_s"] = {"figures": round(t_figures - t_start, 3), "campaign_plots": round(t_plots - t_figures, 3),
                       "sheets": round(t_sheets - t_plots, 3), "heliostats": len(rep["heliostats"]),
                       "total": round(time.perf_counter() - t_start, 3)}
    (out / "report.json").write_text(json.dumps(rep, indent=1, ensure_ascii=False, default=_json_default))
    index = out / "index.html"
    index.write_text(html.index_page(rep, images, rep["heliostats"], site), encoding="utf-8")
    return index


def _json_default(value):
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return value.as_posix()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


PARALLEL_MIN_HELIOSTATS = 40
"""Fields at least this big draw their sheets in several processes (``jobs``)."""

_JOB: dict = {}
"""The sheet job a forked worker inherits (set just before the pool forks)."""


def write_sheet(data: CampaignData, rep: dict, out_dir, heliostat_id: str, site=None) -> dict:
    """One heliostat's sheet exactly as the report draws it (page, plots, frames, JSON) in
    ``out_dir/heliostats/``; ``rep`` is :func:`compute` of ``data``. Returns its summary (``href``
    relative to ``out_dir``). The crew console draws its sheets with this."""
    out = Path(out_dir)
    (out / "heliostats").mkdir(parents=True, exist_ok=True)
    if heliostat_id not in data.heliostat_ids:
        from helicalib.errors import ConfigError

        raise ConfigError(f"heliostat {heliostat_id!r} is not in campaign {data.campaign.id if data.campaign else '-'}")
    return _write_sheets(data, rep, out, True, 1, site, only=[heliostat_id])[0]


def _write_sheets(data: CampaignData, rep: dict, out: Path, frames: bool, jobs: int | None = None,
                  site=None, only: list[str] | None = None) -> list[dict]:
    """Each heliostat's plot, frames, JSON and page; returns the sheet summaries for ``report.json``.

    With ``jobs`` > 1 (default: the CPU count, at most 4) and a field of at least
    :data:`PARALLEL_MIN_HELIOSTATS`, the heliostats are split into chunks drawn by forked worker
    processes (each with its own figure); the summaries come back in field order.
    """
    import multiprocessing
    import os

    obs = data.observations
    valid = obs[obs["valid"] & obs["error_mrad"].notna()] if len(obs) else obs
    visits_of: dict[str, dict] = {}
    for v in data.visits:
        visits_of.setdefault(v.heliostat_id, {})[v.id] = v
    history: dict[str, list] = {}
    for v in data.verdict_history:
        history.setdefault(v.heliostat_id, []).append(v)
    _JOB.clear()
    _JOB.update(
        data=data, rep=rep, out=out, frames=frames, names=_file_names(data.heliostat_ids),
        errors=F.present_errors(data), visits_of=visits_of, history=history, site=site,
        groups={str(k): g for k, g in obs.groupby("heliostat_id")} if len(obs) else {}, empty=obs.iloc[0:0],
        targets={h.heliostat_id: h.target_id for h in data.heliostats},
        max_error=float(valid["error_mrad"].max()) if len(valid) else 0.0,
        max_placements=int(valid["iteration"].max()) + 1 if len(valid) else 1,
    )
    ids = data.heliostat_ids if only is None else list(only)
    jobs = min(4, os.cpu_count() or 1) if jobs is None else max(1, int(jobs))
    methods = multiprocessing.get_all_start_methods()
    try:
        if jobs > 1 and len(ids) >= PARALLEL_MIN_HELIOSTATS and "fork" in methods:
            chunks = [ids[k::jobs] for k in range(jobs)]
            with multiprocessing.get_context("fork").Pool(jobs) as pool:
                parts = pool.map(_sheet_chunk, chunks)
            by_id = {s["id"]: s for part in parts for s in part}
            return [by_id[h] for h in ids]
        return _sheet_chunk(ids)
    finally:
        _JOB.clear()


def _sheet_chunk(ids: list[str]) -> list[dict]:
    """Draw and write the sheets of ``ids`` (in this process) from :data:`_JOB`."""
    from helicalib.report.overlay import overlay_latest
    from helicalib.report.sheet_plots import SheetPlotter

    j = _JOB
    data, rep, out = j["data"], j["rep"], j["out"]
    per_tt = rep["tracking_test"]["per_heliostat"]
    t0 = data.campaign.started_s if data.campaign is not None else 0.0
    summaries = []
    with SheetPlotter(rep["acceptance"], F.loop_threshold_mrad(data), (t0, data.end_s), j["max_error"],
                      j["max_placements"], j["site"]) as plotter:
        for hid in ids:
            stem = j["names"][hid]
            sheet = heliostat_sheet(data, hid, j["targets"][hid], j["groups"].get(hid, j["empty"]), j["errors"].get(hid),
                                    per_tt.get(hid), j["visits_of"].get(hid, {}), j["history"].get(hid, ()))
            plot = plotter.draw(sheet, out / "heliostats" / f"{stem}.png")
            frames_info = None
            if j["frames"] and sheet["latest_frames"] is not None:
                drawn = overlay_latest(data.images_dir, sheet["latest_frames"], data.cfg,
                                       out / "heliostats" / f"{stem}_frames.png")
                sheet["latest_frames"]["remeasured"] = drawn["remeasured"]
                sheet["latest_frames"]["note"] = drawn["note"]
                frames_info = {"src": drawn["png"].name if drawn["png"] is not None else None, "note": drawn["note"]}
            (out / "heliostats" / f"{stem}.json").write_text(
                json.dumps(sheet, indent=1, ensure_ascii=False, default=_json_default))
            (out / "heliostats" / f"{stem}.html").write_text(
                html.sheet_page(sheet, plot.name, frames_info, f"{stem}.json", j["site"], rep["limits"]), encoding="utf-8")
            summary = {k: v for k, v in sheet.items() if k not in ("observation_rows",)}
            summary.update(href=f"heliostats/{stem}.html", json=f"heliostats/{stem}.json",
                           plot=f"heliostats/{plot.name}",
                           frames_png=f"heliostats/{frames_info['src']}" if frames_info and frames_info["src"] else None)
            summaries.append(summary)
    return summaries
