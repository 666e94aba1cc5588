"""The per-heliostat plot of a sheet: one figure reused for every heliostat of the field.

Four panels. Three show **placement errors** (:mod:`helicalib.report.measures`) with the loop
threshold, their own limit: against sun elevation (the 5–15° acceptance band and the high
elevation limit shaded), against time (each day's rising and setting bands and the high-elevation
windows shaded), and before and after each correction of every visit. The fourth shows the
**acceptance error** of each verdict over the campaign with the acceptance limit, its own limit
(hollow: provisional, before the bands and windows were covered). Invalid observations are drawn
as grey crosses along the bottom edge so the crew sees when a visit failed.

Every sheet shares the same axes (0–90° elevation, the whole campaign in time, a log error axis
from :data:`Y_MIN_MRAD` to the field's largest error), so sheets compare at a glance and the
figure is drawn ONCE: :class:`SheetPlotter` keeps that background, and for each heliostat only
restores it, draws the few data artists (matplotlib blitting) and writes the pixels with OpenCV.
A sheet costs a few tens of milliseconds.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402

from helicalib.report.measures import label as measure_label  # noqa: E402
from helicalib.report.plots import (LIMIT_COLOURS, MAX_WIDTH_IN, STYLE, finish, new_figure,  # noqa: E402
                                    time_axis, to_dates)

Y_MIN_MRAD = 0.1
"""Bottom of the log error axis [mrad]; invalid observations are drawn just above it."""

BAND_COLOUR = "#f4a261"
WINDOW_COLOURS = ("#a8dadc", "#d8f3dc")


class SheetPlotter:
    """Draws sheets into PNG files; call :meth:`close` at the end (or use it as a context manager).

    Parameters
    ----------
    spans : dict
        :func:`helicalib.report.sheets.acceptance_spans` (bands and windows; limits).
    loop_threshold_mrad : float
        The closed-loop threshold, drawn on the placement-error panels.
    time_range_s : (float, float)
        The campaign's start and end [UTC s]: the time axis of every sheet.
    max_error_mrad : float
        The largest valid error of the field [mrad]: the top of every error axis.
    max_placements : int
        The most placements of any visit (the corrections panel's x range).
    site : SiteTime, optional
        The site's clock, shown above the time axes (:mod:`helicalib.geometry.sitetime`).
    """

    def __init__(self, spans: dict, loop_threshold_mrad: float, time_range_s: tuple[float, float],
                 max_error_mrad: float, max_placements: int, site=None):
        self.spans = spans
        self.site = site
        self.loop_threshold_mrad = loop_threshold_mrad
        self.fig, axes = new_figure(2, 2, figsize=(MAX_WIDTH_IN, 10.6))
        self.axes = axes.ravel()
        self.fig.subplots_adjust(left=0.07, right=0.965, bottom=0.105, top=0.855, wspace=0.22, hspace=0.8)
        a_el, a_t, a_c, a_acc = self.axes
        self.y_top = max(2.0 * loop_threshold_mrad, 1.3 * max_error_mrad, 1.0)
        self.y_invalid = Y_MIN_MRAD * 1.25
        with matplotlib.rc_context(STYLE):
            self.rising, = a_el.plot([], [], "^", ms=6, color="#1f77b4", label="valid, sun rising")
            self.setting, = a_el.plot([], [], "v", ms=6, color="#ff7f0e", label="valid, sun setting")
            self.el_invalid, = a_el.plot([], [], "x", color="#777", ms=6, label="invalid (bottom row)")
            self.t_valid, = a_t.plot([], [], "o", ms=5, color="#1d3557", label="valid")
            self.t_invalid, = a_t.plot([], [], "x", color="#777", ms=6, label="invalid (bottom row)")
            self.corr, = a_c.plot([], [], "o-", ms=5, lw=1, color="#1d3557", alpha=0.7, label="placements of one visit")
            self.corr_last, = a_c.plot([], [], "s", ms=7, color="#e76f51", label="last placement of a visit")
            self.acc_ok, = a_acc.plot([], [], "o", ms=6, color="#1d3557", label="verdict")
            self.acc_prov, = a_acc.plot([], [], "o", ms=6, mfc="none", color="#888",
                                        label="provisional (before coverage)")
            self.title = self.fig.text(0.5, 0.975, "", ha="center", va="center", fontsize=STYLE["figure.titlesize"])
            self.notes = [ax.text(0.5, 0.5, "", ha="center", va="center", transform=ax.transAxes, color="#666",
                                  fontsize=STYLE["font.size"]) for ax in self.axes]
        self.dynamic = [self.rising, self.setting, self.el_invalid, self.t_valid, self.t_invalid, self.corr,
                        self.corr_last, self.acc_ok, self.acc_prov, *self.notes]
        for art in self.dynamic + [self.title]:
            art.set_animated(True)
        self._static(time_range_s, max_placements)
        self.fig.canvas.draw()
        self.background = self.fig.canvas.copy_from_bbox(self.fig.bbox)

    def __enter__(self) -> "SheetPlotter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        import matplotlib.pyplot as plt

        plt.close(self.fig)

    # ------------------------------------------------------------------ drawn once
    def _static(self, time_range_s, max_placements: int) -> None:
        with matplotlib.rc_context(STYLE):
            self._static_styled(time_range_s, max_placements)
        finish(self.fig)

    def _static_styled(self, time_range_s, max_placements: int) -> None:
        a_el, a_t, a_c, a_acc = self.axes
        sp = self.spans
        t0, t1 = time_range_s
        if sp.get("available"):
            lo, hi = sp["low_band_deg"]
            a_el.axvspan(lo, hi, color=BAND_COLOUR, alpha=0.3, lw=0, label=f"acceptance band {lo:g}–{hi:g}°")
            a_el.axvline(sp["high_elevation_deg"], color="#457b9d", ls=":", lw=1.5,
                         label=f"high windows above {sp['high_elevation_deg']:g}°")
            first_band = first_win = True
            for d in sp["days"]:
                for key in ("rising_band_s", "setting_band_s"):
                    a, b = d[key]
                    if a is not None and b is not None:
                        a_t.axvspan(*to_dates([a, b]), color=BAND_COLOUR, alpha=0.3, lw=0,
                                    label=f"{lo:g}–{hi:g}° rising/setting band" if first_band else None)
                        first_band = False
                for k, (a, b) in enumerate(d["high_windows_s"]):
                    a_t.axvspan(*to_dates([a, b]), color=WINDOW_COLOURS[k % 2], alpha=0.5, lw=0,
                                label=f"{sp['n_windows']} high windows a day" if first_win else None)
                    first_win = False
            a_acc.axhline(sp["max_rms_mrad"], color=LIMIT_COLOURS["acceptance"], ls="--", lw=1.5,
                          label=f"acceptance limit {sp['max_rms_mrad']:g} mrad")
        for ax in (a_el, a_t, a_c):
            ax.axhline(self.loop_threshold_mrad, color=LIMIT_COLOURS["loop"], ls="--", lw=1.5,
                       label=f"loop threshold {self.loop_threshold_mrad:g} mrad")
        a_el.set_xlabel("sun elevation [deg]")
        a_el.set_title("placement errors against sun elevation")
        a_el.set_xlim(0, 90)
        for ax in (a_t, a_acc):
            ax.set_xlim(*to_dates([t0, max(t1, t0 + 3600.0)]))
            time_axis(ax, self.site, t0)
        a_t.set_title("placement errors against time (paper 2.4 bands and windows)")
        a_c.set_xlim(-0.3, max(1, max_placements - 1) + 0.3)
        a_c.set_xlabel("placement in the visit (0 = model, 1.. = corrections) [-]")
        a_c.set_title("placement errors before and after each correction")
        a_c.xaxis.get_major_locator().set_params(integer=True)
        a_acc.set_title("acceptance error of each verdict")
        for ax, key in ((a_el, "placement_error"), (a_t, "placement_error"), (a_c, "placement_error"),
                        (a_acc, "acceptance_error")):
            ax.set_yscale("log")
            ax.set_ylim(Y_MIN_MRAD, self.y_top)
            ax.set_ylabel(measure_label(key))
            ax.grid(alpha=0.3, which="both")
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)

    # ------------------------------------------------------------------ per heliostat
    def draw(self, sheet: dict, path: Path) -> Path:
        """Draw one heliostat's sheet (:func:`helicalib.report.sheets.heliostat_sheet`) into ``path``."""
        import cv2

        rows = sheet["observation_rows"]
        valid = [r for r in rows if r["valid"] and r["error_mrad"] is not None]
        invalid = [r for r in rows if not (r["valid"] and r["error_mrad"] is not None)]
        rising = [r for r in valid if r["sun_rising"]]
        setting = [r for r in valid if not r["sun_rising"]]

        def err(pts):
            return np.clip([r["error_mrad"] for r in pts], Y_MIN_MRAD, self.y_top)

        def err_of(verdicts):
            return np.clip([v["rms_mrad"] for v in verdicts], Y_MIN_MRAD, self.y_top)

        self.rising.set_data([r["sun_elevation_deg"] for r in rising], err(rising))
        self.setting.set_data([r["sun_elevation_deg"] for r in setting], err(setting))
        self.el_invalid.set_data([r["sun_elevation_deg"] for r in invalid], [self.y_invalid] * len(invalid))
        self.t_valid.set_data(to_dates([r["capture_time_s"] for r in valid]), err(valid))
        self.t_invalid.set_data(to_dates([r["capture_time_s"] for r in invalid]), [self.y_invalid] * len(invalid))
        xs, ys, lx, ly = [], [], [], []
        for c in sheet["corrections"]:
            if c["errors_mrad"]:
                xs += c["iterations"] + [np.nan]
                ys += c["errors_mrad"] + [np.nan]
                lx.append(c["iterations"][-1])
                ly.append(c["errors_mrad"][-1])
        self.corr.set_data(xs, np.clip(ys, Y_MIN_MRAD, self.y_top) if ys else [])
        self.corr_last.set_data(lx, np.clip(ly, Y_MIN_MRAD, self.y_top) if ly else [])
        self.notes[0].set_text("" if rows else "no observation")
        self.notes[1].set_text("" if rows else "no observation")
        self.notes[2].set_text("" if lx else "no valid placement")
        hist = [v for v in sheet.get("verdict_history") or [] if v["rms_mrad"] is not None]
        done = [v for v in hist if v["coverage_complete"]]
        prov = [v for v in hist if not v["coverage_complete"]]
        self.acc_ok.set_data(to_dates([v["time_s"] for v in done]), err_of(done))
        self.acc_prov.set_data(to_dates([v["time_s"] for v in prov]), err_of(prov))
        self.notes[3].set_text("" if hist else "no verdict")
        self.title.set_text(f"{sheet['id']} — {sheet['status']}: {len(valid)} valid of {len(rows)} observations, "
                            f"{len(lx)} visits with a valid placement")
        canvas = self.fig.canvas
        canvas.restore_region(self.background)
        for art in self.dynamic:
            art.axes.draw_artist(art)
        self.fig.draw_artist(self.title)
        rgba = np.asarray(canvas.buffer_rgba())
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(path), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1]):
            raise OSError(f"could not write {path}")
        return path
