"""T/GRLM 02-2014 figure 3 and the clause 8.2 verdict from a campaign's stored observations (pure).

The tracking accuracy the standard judges is how well a heliostat tracks on its own model, so the
report uses each visit's FIRST placement (``iteration == 0``, valid, with a recorded wind): the
error before any closed-loop correction. Figure 3 is the fraction of those errors within
``tracking_test.threshold_mrad`` (3.5 mrad) in 1 m/s wind bins; clause 8.2 requires, in each
configured bin (``wind_ms ± bin_half_width_ms``), a fraction STRICTLY above ``min_fraction``
(99 % at 4 m/s, 62 % at 8 m/s, 33 % at 11 m/s). A bin without any point leaves the verdict
``'incomplete'``: the campaign did not meet that wind. The verdict is
:func:`helicalib.calibration.tracking_test.tracking_test`'s; figure 3 here pools the field's points
(one bar per 1 m/s class) so that it stays readable for hundreds of heliostats.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from helicalib.report.figures import num

DEFAULT_SPEC = {"threshold_mrad": 3.5, "bin_half_width_ms": 1.0,
                "wind_bins": [{"wind_ms": 4.0, "min_fraction": 0.99}, {"wind_ms": 8.0, "min_fraction": 0.62},
                              {"wind_ms": 11.0, "min_fraction": 0.33}]}
"""Clause 8.2 as written, used when the field config cannot be read."""


def spec_of(cfg) -> dict:
    """The clause-8.2 settings of a field config (``tracking_test``), or :data:`DEFAULT_SPEC`."""
    if cfg is None:
        return DEFAULT_SPEC
    t = cfg.tracking_test
    return {"threshold_mrad": float(t.threshold_mrad), "bin_half_width_ms": float(t.bin_half_width_ms),
            "wind_bins": [{"wind_ms": float(b.wind_ms), "min_fraction": float(b.min_fraction)} for b in t.wind_bins]}


def first_placements(obs: pd.DataFrame) -> pd.DataFrame:
    """Valid first placements (iteration 0) with an error and a wind: the points clause 8.2 judges."""
    if not len(obs):
        return obs
    keep = obs["valid"] & (obs["iteration"] == 0) & obs["error_mrad"].notna() & obs["wind_ms"].notna()
    return obs[keep]


def _spec_model(spec: dict):
    from helicalib.config import TrackingTest

    return TrackingTest.model_validate(spec)


def clause_8_2(errors_mrad, wind_ms, spec: dict) -> dict:
    """The clause 8.2 verdict of a set of tracking errors and their winds.

    :func:`helicalib.calibration.tracking_test.tracking_test` as JSON: ``verdict`` ('pass', 'fail'
    or 'incomplete'), ``message``, ``n``, ``accuracy_rms_mrad``, ``fraction_within`` and ``bins``
    (``wind_ms``, ``low_ms``, ``high_ms``, ``n``, ``within``, ``fraction``, ``required``, ``pass``;
    ``pass`` is None for a bin without points).
    """
    from helicalib.calibration.tracking_test import tracking_test as _test

    out = _test(np.asarray(errors_mrad, dtype=float), np.asarray(wind_ms, dtype=float), _spec_model(spec)).to_json()
    for b in out["bins"]:
        b["fraction"] = num(b["fraction"])
    return explain(out)


NO_DATA = "no data at this wind (not a failure)"
"""What a clause 8.2 wind bin without a measurement says."""

BIN_STATUS = {True: "met", False: "not met", None: "no data"}
"""A bin's ``status`` by its ``pass`` (None: no first placement at that wind)."""


def _bin_name(b: dict) -> str:
    return f"{b['wind_ms']:g} m/s ({b['low_ms']:g}–{b['high_ms']:g} m/s)"


def explain(verdict: dict) -> dict:
    """Add plain sentences to a clause 8.2 verdict (:func:`clause_8_2`), per bin and overall.

    Each bin gains ``status`` (``'met'``, ``'not met'``, ``'no data'``) and ``text``; a bin without
    a point says :data:`NO_DATA`. The verdict gains ``measured_ms`` and ``missing_ms`` (bin centres
    with and without data), ``summary`` (one sentence saying which bins were measured and how they
    did, and which are missing) and ``short`` (the same in a few words, for table cells).
    """
    thr = verdict["threshold_mrad"]
    for b in verdict["bins"]:
        b["status"] = BIN_STATUS[b["pass"]]
        if b["pass"] is None:
            b["text"] = f"{_bin_name(b)}: {NO_DATA}"
        else:
            b["text"] = (f"{_bin_name(b)}: {b['within']} of {b['n']} first placements within {thr:g} mrad "
                         f"({100 * b['fraction']:.1f} %, needs more than {100 * b['required']:g} %): {b['status']}")
    measured = [b for b in verdict["bins"] if b["pass"] is not None]
    missing = [b for b in verdict["bins"] if b["pass"] is None]
    verdict["measured_ms"] = [b["wind_ms"] for b in measured]
    verdict["missing_ms"] = [b["wind_ms"] for b in missing]
    said = "; ".join(f"{b['wind_ms']:g} m/s {b['status']} ({b['within']}/{b['n']})" for b in measured)
    names = [f"{b['wind_ms']:g} m/s" for b in missing]
    lacking = (", ".join(names[:-1]) + " and " + names[-1]) if len(names) > 1 else "".join(names)
    if verdict["verdict"] == "pass":
        summary = f"Passes clause 8.2 in every wind bin: {said}."
    elif verdict["verdict"] == "fail":
        summary = f"Fails clause 8.2: {said}." + (f" No data at {lacking} (not a failure)." if missing else "")
    elif measured:
        summary = (f"Not judged yet: no data at {lacking}, winds the campaign has not met (not a failure). "
                   f"Measured: {said}.")
    else:
        summary = f"Not judged yet: no first placement at any clause 8.2 wind ({lacking}); not a failure."
    verdict["summary"] = summary
    verdict["short"] = ", ".join(f"{b['wind_ms']:g} m/s {b['status']}" for b in verdict["bins"])
    return verdict


def figure_3(errors_mrad, wind_ms, threshold_mrad: float, step_ms: float = 1.0, max_ms: float = 14.0) -> dict:
    """Fraction of errors within the threshold in ``step_ms`` wind bins from 0 to ``max_ms`` (or the largest wind)."""
    e = np.abs(np.asarray(errors_mrad, dtype=float))
    w = np.asarray(wind_ms, dtype=float)
    top = max(max_ms, float(np.ceil(w.max() / step_ms) * step_ms) if w.size else 0.0)
    edges = np.arange(0.0, top + step_ms / 2, step_ms)
    if edges.size < 2:
        edges = np.array([0.0, step_ms])
    k = np.clip(np.searchsorted(edges, w, side="right") - 1, 0, edges.size - 2)
    n = np.bincount(k, minlength=edges.size - 1)
    within = np.bincount(k, weights=(e <= threshold_mrad).astype(float), minlength=edges.size - 1).astype(int)
    return {"edges_ms": [num(x) for x in edges], "n": n.tolist(), "within": within.tolist(),
            "fraction": [num(a / b) if b else None for a, b in zip(within, n)]}


def tracking_test(obs: pd.DataFrame, cfg) -> dict:
    """Field-wide figure 3 and clause 8.2 verdict, and the verdict of each heliostat."""
    spec = spec_of(cfg)
    pts = first_placements(obs)
    e = pts["error_mrad"].to_numpy(float) if len(pts) else np.zeros(0)
    w = pts["wind_ms"].to_numpy(float) if len(pts) else np.zeros(0)
    per = {}
    if len(pts):
        for hid, g in pts.groupby("heliostat_id"):
            per[str(hid)] = clause_8_2(g["error_mrad"].to_numpy(float), g["wind_ms"].to_numpy(float), spec)
    return {"spec": spec, "points": "valid first placements (iteration 0) with a recorded wind",
            "figure_3": figure_3(e, w, spec["threshold_mrad"]), "field": clause_8_2(e, w, spec),
            "per_heliostat": per}
