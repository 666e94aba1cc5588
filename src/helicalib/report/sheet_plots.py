"""The per-heliostat plot of a sheet: one figure reused for every heliostat of the field.

Three panels: tracking error against sun elevation (the 5–15° acceptance band and the high
elevation limit shaded), against time (each day's rising and setting bands and the high-elevation
windows shaded), and the error before and after each correction of every visit. Invalid
observations are drawn as grey crosses on the time axis of each panel (error 0) so the crew sees
when a visit failed. :class:`SheetPlotter` clears and redraws the same three axes for each
heliostat, which keeps a 500-heliostat report fast.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from helicalib.report.plots import DPI, time_axis, to_dates  # noqa: E402

BAND_COLOUR = "#f4a261"
WINDOW_COLOURS = ("#a8dadc", "#d8f3dc")


class SheetPlotter:
    """Draws sheets into PNG files; call :meth:`close` at the end (or use it as a context manager).

    Parameters
    ----------
    spans : dict
        :func:`helicalib.report.sheets.acceptance_spans`.
    loop_threshold_mrad : float
        The closed-loop threshold, drawn on the corrections panel.
    """

    def __init__(self, spans: dict, loop_threshold_mrad: float):
        self.spans = spans
        self.loop_threshold_mrad = loop_threshold_mrad
        self.fig, self.axes = plt.subplots(1, 3, figsize=(15, 4.2), layout="constrained")

    def __enter__(self) -> "SheetPlotter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        plt.close(self.fig)

    def draw(self, sheet: dict, path: Path) -> Path:
        """Draw one heliostat's sheet (:func:`helicalib.report.sheets.heliostat_sheet`) into ``path``."""
        a_el, a_t, a_c = self.axes
        for ax in self.axes:
            ax.cla()
        rows = sheet["observation_rows"]
        valid = [r for r in rows if r["valid"] and r["error_mrad"] is not None]
        invalid = [r for r in rows if not (r["valid"] and r["error_mrad"] is not None)]
        self._elevation(a_el, valid, invalid)
        self._time(a_t, valid, invalid)
        self._corrections(a_c, sheet["corrections"])
        self.fig.suptitle(f"{sheet['id']} — {sheet['status']}", fontsize=11)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.fig.savefig(path, dpi=DPI)
        return path

    # ------------------------------------------------------------------ panels
    def _limits(self, ax) -> None:
        sp = self.spans
        if sp.get("available"):
            ax.axhline(sp["max_rms_mrad"], color="#2a9d3a", ls="--", lw=1, label=f"max RMS {sp['max_rms_mrad']:g} mrad")

    def _elevation(self, ax, valid, invalid) -> None:
        sp = self.spans
        if sp.get("available"):
            lo, hi = sp["low_band_deg"]
            ax.axvspan(lo, hi, color=BAND_COLOUR, alpha=0.3, lw=0, label=f"acceptance band {lo:g}–{hi:g}°")
            ax.axvline(sp["high_elevation_deg"], color="#457b9d", ls=":", lw=1,
                       label=f"high windows above {sp['high_elevation_deg']:g}°")
        self._limits(ax)
        rising = [r for r in valid if r["sun_rising"]]
        setting = [r for r in valid if not r["sun_rising"]]
        for pts, marker, label in ((rising, "^", "valid, sun rising"), (setting, "v", "valid, sun setting")):
            if pts:
                ax.plot([r["sun_elevation_deg"] for r in pts], [r["error_mrad"] for r in pts], marker, ls="none",
                        ms=5, label=label)
        if invalid:
            ax.plot([r["sun_elevation_deg"] for r in invalid], [0.0] * len(invalid), "x", color="#888", ms=5,
                    label=f"invalid ({len(invalid)})")
        ax.set_xlabel("sun elevation [deg]")
        ax.set_ylabel("tracking error [mrad]")
        ax.set_title("observations against sun elevation", fontsize=10)
        ax.set_ylim(bottom=-0.3)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")

    def _time(self, ax, valid, invalid) -> None:
        sp = self.spans
        times = [r["capture_time_s"] for r in valid + invalid]
        if sp.get("available") and times:
            t0, t1 = min(times) - 3600.0, max(times) + 3600.0
            first = True
            for d in sp["days"]:
                for key in ("rising_band_s", "setting_band_s"):
                    a, b = d[key]
                    if a is not None and b is not None and b > t0 and a < t1:
                        ax.axvspan(*to_dates([a, b]), color=BAND_COLOUR, alpha=0.3, lw=0,
                                   label="rising/setting band" if first else None)
                        first = False
                for k, (a, b) in enumerate(d["high_windows_s"]):
                    if b > t0 and a < t1:
                        ax.axvspan(*to_dates([a, b]), color=WINDOW_COLOURS[k % 2], alpha=0.5, lw=0,
                                   label="high windows" if k == 0 and d is sp["days"][0] else None)
        self._limits(ax)
        if valid:
            ax.plot(to_dates([r["capture_time_s"] for r in valid]), [r["error_mrad"] for r in valid], "o", ms=4,
                    color="#1d3557", label="valid")
        if invalid:
            ax.plot(to_dates([r["capture_time_s"] for r in invalid]), [0.0] * len(invalid), "x", color="#888",
                    ms=5, label="invalid")
        if times:
            ax.set_xlim(*to_dates([min(times) - 1800.0, max(times) + 1800.0]))
            time_axis(ax)
        else:
            ax.set_xlabel("time (UTC)")
            ax.text(0.5, 0.5, "no observation", ha="center", va="center", transform=ax.transAxes, color="#666")
        ax.set_ylabel("tracking error [mrad]")
        ax.set_title("observations against time (bands and windows of paper 2.4)", fontsize=10)
        ax.set_ylim(bottom=-0.3)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")

    def _corrections(self, ax, corrections) -> None:
        drawn = 0
        for c in corrections:
            if c["errors_mrad"]:
                ax.plot(c["iterations"], c["errors_mrad"], "o-", ms=4, lw=1, alpha=0.8)
                drawn += 1
        ax.axhline(self.loop_threshold_mrad, color="#d1495b", ls="--", lw=1,
                   label=f"loop threshold {self.loop_threshold_mrad:g} mrad")
        ax.set_xlabel("placement in the visit (0 = model, 1.. = after each correction) [-]")
        ax.set_ylabel("tracking error [mrad]")
        ax.set_title(f"error before and after each correction ({drawn} visits)", fontsize=10)
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
        if not drawn:
            ax.text(0.5, 0.5, "no valid placement", ha="center", va="center", transform=ax.transAxes, color="#666")
