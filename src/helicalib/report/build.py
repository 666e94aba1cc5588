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
from helicalib.report import html
from helicalib.report import plots as campaign_plots
from helicalib.report.data import CampaignData, load_campaign
from helicalib.report.grlm import spec_of, tracking_test
from helicalib.report.measures import glossary
from helicalib.report.overview import overview
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


PREDICTION_MAX_HELIOSTATS = 500
"""Fields up to this size get the year-round prediction by default: it fits every heliostat again
(seconds each), hours on a 10⁴-heliostat field; ``predictions=True`` asks for it on any field."""


def compute(data: CampaignData, site: SiteTime | None = None, predictions: bool | None = None) -> dict:
    """Every campaign-level figure of the report (no per-heliostat sheet), as one JSON-ready dict.

    ``predictions``: compute the year-round prediction (default: on fields of at most
    :data:`PREDICTION_MAX_HELIOSTATS` heliostats; ``report.json``'s ``year_prediction_note`` says why not)."""
    from helicalib import __version__

    n = len(data.heliostats)
    predictions = n <= PREDICTION_MAX_HELIOSTATS if predictions is None else bool(predictions)
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
        "year_prediction": year_predictions(data) if predictions else None,
        "year_prediction_note": "" if predictions else (
            f"not computed for {n} heliostats: it fits every heliostat again (seconds each); "
            f"helicalib report --predictions computes it"),
        "events": F.events_log(data),
        "glossary": glossary(limits(data)),
        "limits": limits(data),
        "time_zone": site.to_json(),
    }


FULL_PLOTS_MAX = 500
"""Fields up to this size get every heliostat's drawn plot (PNG); above, only the heliostats needing
attention (not accepted, no verdict) do and every other sheet shows a small inline chart instead."""


def build_report(db_path, out_dir, campaign_id: int | None = None, *, field_config=None, images_dir=None,
                 frames: bool = True, jobs: int | None = None, timezone: str | None = None,
                 plots: str = "auto", predictions: bool | None = None, progress=None) -> Path:
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
    plots : str
        Which sheets get the drawn plot (PNG): ``"all"``, ``"attention"`` (not accepted or no verdict;
        the others an inline chart) or ``"auto"`` (all on fields of at most :data:`FULL_PLOTS_MAX`).
    predictions : bool, optional
        Compute the year-round prediction (default: on fields of at most ``PREDICTION_MAX_HELIOSTATS``).
    progress : callable, optional
        ``progress(done, total, what)`` while the sheets are written.
    """
    t_start = time.perf_counter()
    out = Path(out_dir)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    (out / "heliostats").mkdir(parents=True, exist_ok=True)
    sheet_plots = plots
    if sheet_plots not in ("auto", "all", "attention"):
        from helicalib.errors import ConfigError

        raise ConfigError(f"plots {sheet_plots!r}: expected auto, all or attention")
    data = load_campaign(db_path, campaign_id, field_config, images_dir)
    site = site_time(data.cfg, timezone)
    rep = compute(data, site, predictions)
    if sheet_plots == "auto":
        sheet_plots = "all" if len(data.heliostats) <= FULL_PLOTS_MAX else "attention"
    t_figures = time.perf_counter()

    images = {"field_map": campaign_plots.plot_field_map(rep["field_map"], out / "plots" / "field_map.png"),
              "progress": campaign_plots.plot_progress(rep["progress"], out / "plots" / "progress.png", site),
              "figure_3": campaign_plots.plot_figure_3(rep["tracking_test"], out / "plots" / "grlm_figure3.png")}
    for number, key in ((6, "wind"), (7, "dni"), (8, "cleanliness")):
        images[f"pass_{key}"] = campaign_plots.plot_pass_rate(rep["pass_rate"][key], out / "plots" / f"pass_rate_{key}.png",
                                                     number, rep["pass_rate"]["threshold_mrad"])
    images = {k: v.relative_to(out).as_posix() for k, v in images.items()}
    t_plots = time.perf_counter()

    rep["heliostats"] = _write_sheets(data, rep, out, frames, jobs, site, plots=sheet_plots, progress=progress)
    rep["overview"] = overview(data, rep, rep["heliostats"])
    rep["sheet_plots"] = sheet_plots
    t_sheets = time.perf_counter()
    rep["timing_s"] = {"figures": round(t_figures - t_start, 3), "campaign_plots": round(t_plots - t_figures, 3),
                       "sheets": round(t_sheets - t_plots, 3), "heliostats": len(rep["heliostats"]),
                       "total": round(time.perf_counter() - t_start, 3)}
    (out / "report.json").write_text(json.dumps(rep, indent=1, ensure_ascii=False, default=_json_default))
    index = out / "index.html"
    index.write_text(html.index_page(rep, images, rep["heliostats"], site, static_table=len(data.heliostats) <= FULL_PLOTS_MAX),
                     encoding="utf-8")
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


SHEET_BATCH = 50
"""Heliostats per task of the sheet workers (the progress moves once per batch)."""


def _write_sheets(data: CampaignData, rep: dict, out: Path, frames: bool, jobs: int | None = None,
                  site=None, only: list[str] | None = None, plots: str = "all", progress=None) -> list[dict]:
    """Each heliostat's plot, frames, JSON and page; returns the sheet summaries for ``report.json``.

    With ``jobs`` > 1 (default: the CPU count, at most 4) and a field of at least
    :data:`PARALLEL_MIN_HELIOSTATS`, the heliostats are split into chunks drawn by forked worker
    processes (each with its own figure); the summaries come back in field order. ``plots``:
    ``"all"`` or ``"attention"`` (see :func:`build_report`); ``progress(done, total, what)``.
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
        max_placements=int(valid["iteration"].max()) + 1 if len(valid) else 1, plots=plots,
        n_heliostats=len(data.heliostats),
    )
    ids = data.heliostat_ids if only is None else list(only)
    jobs = min(4, os.cpu_count() or 1) if jobs is None else max(1, int(jobs))
    methods = multiprocessing.get_all_start_methods()
    try:
        batches = [ids[k:k + SHEET_BATCH] for k in range(0, len(ids), SHEET_BATCH)]
        by_id: dict[str, dict] = {}

        def collect(part):
            by_id.update((s["id"], s) for s in part)
            if progress is not None:
                progress(len(by_id), len(ids), "heliostat sheets")

        if jobs > 1 and len(ids) >= PARALLEL_MIN_HELIOSTATS and "fork" in methods:
            with multiprocessing.get_context("fork").Pool(jobs) as pool:
                for part in pool.imap_unordered(_sheet_chunk, batches):
                    collect(part)
        else:
            for batch in batches:
                collect(_sheet_chunk(batch))
        return [by_id[h] for h in ids]
    finally:
        if "plotter" in _JOB:
            _JOB["plotter"].close()
        _JOB.clear()


def _sheet_chunk(ids: list[str]) -> list[dict]:
    """Draw and write the sheets of ``ids`` (in this process) from :data:`_JOB`."""
    from helicalib.report.overlay import overlay_latest

    j = _JOB
    data, rep, out = j["data"], j["rep"], j["out"]
    per_tt = rep["tracking_test"]["per_heliostat"]
    summaries = []
    band = list(rep["acceptance"].get("low_band_deg") or (5.0, 15.0))
    page_limits = {**rep["limits"], "low_band_deg": band}
    for hid in ids:
        stem = j["names"][hid]
        sheet = heliostat_sheet(data, hid, j["targets"][hid], j["groups"].get(hid, j["empty"]), j["errors"].get(hid),
                                per_tt.get(hid), j["visits_of"].get(hid, {}), j["history"].get(hid, ()))
        drawn = j["plots"] == "all" or sheet["status"] != "accepted"
        plot = _plotter().draw(sheet, out / "heliostats" / f"{stem}.png") if drawn else None
        frames_info = None
        if j["frames"] and sheet["latest_frames"] is not None:
            shown = overlay_latest(data.images_dir, sheet["latest_frames"], data.cfg,
                                   out / "heliostats" / f"{stem}_frames.png")
            sheet["latest_frames"]["remeasured"] = shown["remeasured"]
            sheet["latest_frames"]["note"] = shown["note"]
            frames_info = {"src": shown["png"].name if shown["png"] is not None else None, "note": shown["note"]}
        (out / "heliostats" / f"{stem}.json").write_text(  # compact: json's C encoder (indent is pure Python)
            json.dumps(sheet, ensure_ascii=False, default=_json_default))
        (out / "heliostats" / f"{stem}.html").write_text(
            html.sheet_page(sheet, plot.name if plot else None, frames_info, f"{stem}.json", j["site"], page_limits,
                            plot_note="" if plot else _PLOT_NOTE.format(n=j["n_heliostats"])), encoding="utf-8")
        summary = {k: v for k, v in sheet.items() if k not in ("observation_rows",)}
        summary.update(href=f"heliostats/{stem}.html", json=f"heliostats/{stem}.json",
                       plot=f"heliostats/{plot.name}" if plot else None,
                       frames_png=f"heliostats/{frames_info['src']}" if frames_info and frames_info["src"] else None)
        summaries.append(summary)
    return summaries


def _plotter():
    """This process's :class:`SheetPlotter` for :data:`_JOB`, made on first use (its background costs
    seconds: once per worker, not per batch); closed when the job is cleared."""
    from helicalib.report.sheet_plots import SheetPlotter

    j = _JOB
    if "plotter" not in j:
        data = j["data"]
        t0 = data.campaign.started_s if data.campaign is not None else 0.0
        j["plotter"] = SheetPlotter(j["rep"]["acceptance"], F.loop_threshold_mrad(data), (t0, data.end_s),
                                    j["max_error"], j["max_placements"], j["site"])
    return j["plotter"]


_PLOT_NOTE = ("On a field of {n} heliostats the report draws the full plots only for the heliostats that need "
              "attention; helicalib report DB --out DIR --plots all draws them for every heliostat.")
