"""The error measures the report shows: one name each, used the same way in every table, axis and legend.

A campaign produces several different "errors" of a heliostat, and they answer different
questions. Each has one entry in :data:`MEASURES`: a name (the only words the pages use for it),
the JSON keys that carry it, its definition and the limit it is judged against (if any). The
campaign page prints them as its glossary (:func:`glossary`); plots and tables take their labels
from :func:`label`. Limits are drawn only over their own measure: the acceptance limit
(``acceptance.max_rms_mrad``) on acceptance errors, the loop threshold
(``calibration.loop_threshold_mrad``) on placement errors.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Measure:
    """One error measure of the report.

    Attributes
    ----------
    key : str
        Its identifier in :data:`MEASURES` and in ``report.json`` ``glossary``.
    name : str
        The name every page, table, axis and legend uses for it.
    json_keys : tuple of str
        Where ``report.json`` carries it.
    definition : str
        What it is, in one or two sentences.
    limit : str
        The limit it is judged against (``{…}`` fields filled by :func:`glossary`), or ''.
    """

    key: str
    name: str
    json_keys: tuple[str, ...]
    definition: str
    limit: str = ""


MEASURES: dict[str, Measure] = {m.key: m for m in (
    Measure("acceptance_error", "acceptance error",
            ("heliostats[].verdict.rms_mrad", "field_map.heliostats[].acceptance_error_mrad"),
            "The paper's section 2.4 accuracy rule, as the newest verdict computed it: the RMS over the "
            "heliostat's acceptance points (one per valid visit: its last valid measurement) of the "
            "leave-one-visit-out beam angle, i.e. the angle at the pivot between the spot the camera saw "
            "and the spot the heliostat's model fitted without that visit predicts. Until the rising and "
            "setting bands and the high windows are all covered, the verdict takes the RMS of those "
            "points' placement errors instead (provisional; the verdict fails on coverage anyway).",
            "at most {max_rms_mrad:g} mrad (acceptance.max_rms_mrad), with at least {min_points} points"),
    Measure("placement_error", "placement error",
            ("heliostats/<id>.json observation_rows[].error_mrad", "heliostats[].corrections[].errors_mrad"),
            "What each observation records: T/GRLM 02-2014 formula (1) on the board, the distance between the "
            "spot's centre and where the heliostat's current model puts the beam for the strokes it held, "
            "divided by the slant distance, at one placement of a visit (the model's first, or one after "
            "a correction).",
            "loop threshold {loop_threshold_mrad:g} mrad (calibration.loop_threshold_mrad): below it the visit "
            "has converged and no further correction is made"),
    Measure("first_placement_error", "first-placement error",
            ("tracking_test.figure_3", "tracking_test.field", "tracking_test.per_heliostat"),
            "The placement error of a visit's first placement (iteration 0), before any correction: how well "
            "the heliostat tracks on its own model. T/GRLM figure 3 and clause 8.2 count these.",
            "clause 8.2 counts those within {grlm_threshold_mrad:g} mrad (tracking_test.threshold_mrad) per "
            "wind bin"),
    Measure("latest_placement_error", "latest placement error",
            ("heliostats[].present_error_mrad", "field_map.heliostats[].present_error_mrad"),
            "The placement error of the heliostat's newest valid observation, usually the last placement "
            "of its newest visit, i.e. after that visit's corrections.",
            "the loop threshold {loop_threshold_mrad:g} mrad applies to it as to every placement"),
    Measure("placement_error_rms", "placement-error RMS",
            ("heliostats[].valid_rms_mrad",),
            "The RMS of all the heliostat's valid placement errors, first placements and corrections alike. "
            "It mixes errors before and after correction; it is not what acceptance judges.",
            ""),
    Measure("fit_residual_rms", "fit residual RMS",
            ("heliostats[].fit.rms_mrad",),
            "In-sample: the RMS over the valid observations the error model was fitted to of the angle between "
            "the fitted model's beam and the direction to the observed spot. It flatters the model; acceptance "
            "uses the leave-one-visit-out error instead.",
            ""),
)}
"""Every error measure of the report, by key."""


def name(key: str) -> str:
    """The name of measure ``key``."""
    return MEASURES[key].name


def label(key: str, unit: str = "mrad") -> str:
    """An axis or column label: ``'acceptance error [mrad]'``."""
    return f"{MEASURES[key].name} [{unit}]"


def glossary(limits: dict) -> list[dict]:
    """The glossary of the campaign page and ``report.json``: one row per measure.

    ``limits`` holds the campaign's ``max_rms_mrad``, ``min_points``, ``loop_threshold_mrad`` and
    ``grlm_threshold_mrad`` (from its field config, else the documented defaults).
    """
    return [{"key": m.key, "name": m.name, "definition": m.definition,
             "limit": m.limit.format(**limits) if m.limit else None, "json_keys": list(m.json_keys)}
            for m in MEASURES.values()]
