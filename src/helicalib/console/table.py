"""The console's heliostats table: filtered, sorted and paged on the server (pure).

At 10⁴ heliostats the page never holds the whole table: ``GET /api/heliostats`` answers one page
of it (:func:`query`) from the rows :meth:`helicalib.store.sqlite.Store.progress` gives, with each
heliostat's map state (:data:`helicalib.console.view.STATES`) and verdict
(:func:`helicalib.campaign.progress_summary.row_state`) added. Query parameters:

==============  ====================================================================
``board``       a target id (its heliostats only)
``verdict``     ``accepted``, ``not-accepted``, ``no-verdict``, ``out-of-service``
``state``       a map state (``waiting``, ``on-board``, ``accepted``, ``refused``, ``attention``)
``q``           text in the heliostat's id (any case)
``min_error``   last valid error at least this [mrad] (heliostats without one are left out)
``max_error``   last valid error at most this [mrad]
``sort``        a column of :data:`SORTS` (default ``block``: the field's order)
``order``       ``asc`` (default) or ``desc``; heliostats without a value come last either way
``offset``      the first row of the page (default 0)
``limit``       rows per page (default :data:`PAGE_ROWS`, at most :data:`MAX_PAGE_ROWS`)
==============  ====================================================================
"""

from __future__ import annotations

import math

from helicalib.campaign.progress_summary import first_missing, row_state
from helicalib.errors import ConfigError

PAGE_ROWS = 50
MAX_PAGE_ROWS = 500
SORTS = ("block", "heliostat_id", "target_id", "state", "verdict", "visits", "valid", "last_error_mrad", "rms_mrad")
VERDICTS = {"accepted": "accepted", "not-accepted": "not accepted", "no-verdict": "no verdict",
            "out-of-service": "out of service"}
PARAMS = ("board", "verdict", "state", "q", "min_error", "max_error", "sort", "order", "offset", "limit")


def table_rows(progress: list[dict], states: dict[str, str], out_of_service) -> list[dict]:
    """The table's rows: ``progress`` (block order) with ``block``, ``state``, ``verdict``, ``missing``."""
    return [{"block": i, "heliostat_id": r["heliostat_id"], "target_id": r["target_id"],
             "state": states.get(r["heliostat_id"], "waiting"), "verdict": row_state(r, out_of_service),
             "missing": first_missing(r), "visits": r["visits"], "valid": r["valid"],
             "last_error_mrad": _round(r["last_error_mrad"]), "rms_mrad": _round(r["rms_mrad"])}
            for i, r in enumerate(progress)]


def _round(x):
    return None if x is None or not math.isfinite(float(x)) else round(float(x), 3)


def _number(params, name: str) -> float | None:
    text = params.get(name)
    if text is None or str(text).strip() == "":
        return None
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"heliostats table: {name}={str(text)[:40]!r} is not a number") from None
    if not math.isfinite(value):
        raise ConfigError(f"heliostats table: {name}={str(text)[:40]!r} is not a finite number")
    return value


def _whole(params, name: str, default: int, low: int, high: int) -> int:
    text = params.get(name)
    if text is None or str(text).strip() == "":
        return default
    if not (str(text).strip().isascii() and str(text).strip().isdigit()):
        raise ConfigError(f"heliostats table: {name}={str(text)[:40]!r} is not a whole number")
    if len(str(text).strip()) > 12:  # int() refuses more than 4300 digits; no page is that far
        raise ConfigError(f"heliostats table: {name}={str(text)[:40]!r} is not in {low}..{high}")
    value = int(text)
    if not low <= value <= high:
        raise ConfigError(f"heliostats table: {name}={value} is not in {low}..{high}")
    return value


def query(rows: list[dict], params) -> dict:
    """One page of ``rows`` as ``params`` (a mapping of the query parameters) asks; a
    :class:`ConfigError` naming the parameter for a value it cannot take."""
    unknown = [k for k in params if k not in PARAMS and k != "token"]
    if unknown:
        raise ConfigError(f"heliostats table: unknown parameter {unknown[0][:40]!r} (the parameters are "
                          f"{', '.join(PARAMS)})")
    board, verdict, state = params.get("board") or None, params.get("verdict") or None, params.get("state") or None
    if verdict is not None and verdict not in VERDICTS:
        raise ConfigError(f"heliostats table: verdict={verdict[:40]!r} is not one of {', '.join(VERDICTS)}")
    text = (params.get("q") or "").strip().lower()
    low, high = _number(params, "min_error"), _number(params, "max_error")
    sort = params.get("sort") or "block"
    if sort not in SORTS:
        raise ConfigError(f"heliostats table: sort={sort[:40]!r} is not one of {', '.join(SORTS)}")
    order = params.get("order") or "asc"
    if order not in ("asc", "desc"):
        raise ConfigError(f"heliostats table: order={order[:40]!r} is not asc or desc")
    offset = _whole(params, "offset", 0, 0, 10**9)
    limit = _whole(params, "limit", PAGE_ROWS, 1, MAX_PAGE_ROWS)
    want = VERDICTS.get(verdict)
    picked = [r for r in rows
              if (board is None or r["target_id"] == board) and (want is None or r["verdict"] == want)
              and (state is None or r["state"] == state) and (not text or text in r["heliostat_id"].lower())
              and (low is None or (r["last_error_mrad"] is not None and r["last_error_mrad"] >= low))
              and (high is None or (r["last_error_mrad"] is not None and r["last_error_mrad"] <= high))]
    have = [r for r in picked if r[sort] is not None]
    none = [r for r in picked if r[sort] is None]
    have.sort(key=lambda r: r[sort], reverse=order == "desc")  # stable: ties keep the field's order
    ordered = have + none
    return {"total": len(rows), "matched": len(ordered), "offset": offset, "limit": limit, "sort": sort,
            "order": order, "rows": ordered[offset:offset + limit],
            "boards": sorted({r["target_id"] for r in rows}), "verdicts": list(VERDICTS)}
