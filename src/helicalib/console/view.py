"""The console page's figures: read from the campaign database (read-only) and the newest snapshot.

:func:`read_view` is the only I/O: one read-only :class:`~helicalib.store.Store` connection of
the console's own (never the controller's, never the owner lock), so reading never blocks the
control loop and works as well on a campaign another process runs. The result is a plain dict
the templates draw (``templates/panels.html``):

* ``clock``: plant time (the controller's snapshot, or the newest record of the database);
* ``gate``: wind, DNI, the limits of the field config, stowed or not and why, paused by the crew;
* ``boards``: per board the heliostat on it, placement, last error, since when, its newest frames;
* ``map``: every heliostat's position and state (:data:`STATES`);
* ``progress``: accepted, and today's bands with how many heliostats still need each;
* ``events``: the newest stored events with their reasons, and the crew's actions.
"""

from __future__ import annotations

import json
import math
import sqlite3
from contextlib import contextmanager
from dataclasses import dataclass, field

from helicalib.errors import DataError, HelicalibError

STATES = {
    "waiting": "waiting for its turn (no verdict yet, or not accepted)",
    "on-board": "on a board now",
    "accepted": "accepted",
    "refused": "the plant refused its last visit, or the crew took it out of service",
    "attention": "needs attention: its last visit faulted, or it is not confirmed back to tracking",
}
"""Heliostat states on the field map, with their meaning (the legend)."""
EVENTS_SHOWN = 300
STATE_EVENT_KINDS = ("gated", "ungated", "stow", "resume", "plant_lost", "plant_back", "off_tracking",
                     "back_to_tracking")
"""The events the page's state is made of (the gate, the plant, heliostats off tracking)."""
MAP_SVG_MAX = 500
"""Fields of at most this many heliostats are drawn as SVG (a link and a tooltip per heliostat);
larger ones on a canvas from one compact list (:func:`_map`), 10⁴ points in milliseconds."""
FRAMES_KEPT = 50
"""Observations whose frames the page may ask for (the boards' newest; older ones are forgotten)."""
PLOT_AFTER_S = 600.0
"""The acceptance plot is drawn once the campaign has run this long (plant time); before, the panel says so."""
_DAYS: dict = {}


@dataclass
class Sources:
    """Where a view reads from: the database (read-only store), the field config, the campaign."""

    store: object
    cfg: object
    campaign_id: int
    site: object
    armed_actions: bool = False
    frames: dict = field(default_factory=dict)
    """Observation id → the ``latest`` dict :func:`helicalib.report.overlay.overlay_latest` draws."""
    images_dir: object = None
    """The frames folder when given (``--images``, or the controller's own); None: the folder the
    campaign recorded at its start (:meth:`~helicalib.store.sqlite.Store.campaign_images_dir`)."""

    ids: list | None = None
    """The campaign's heliostat ids in block order (read once: they never change)."""
    verdicts: dict = field(default_factory=dict)
    verdicts_max_id: int = 0
    """The newest verdicts read so far and the highest verdict row id among them (verdicts are only
    ever added: each view reads those recorded since)."""
    positions: dict | None = None
    """The map's drawing of the field (positions never change during a campaign): see :func:`_map`."""

    def heliostat_ids(self) -> list:
        if self.ids is None:
            self.ids = [h.heliostat_id for h in self.store.campaign_heliostats(self.campaign_id)]
        return self.ids

    def latest_verdicts(self) -> dict:
        """Each heliostat's newest verdict, read incrementally."""
        new = self.store.latest_verdicts(self.campaign_id, after_id=self.verdicts_max_id)
        if new:
            self.verdicts = {**self.verdicts, **new}
            self.verdicts_max_id = max(self.verdicts_max_id, *(v.id for v in new.values()))
        return self.verdicts

    def frames_dir(self):
        """Where the campaign's frame files are (the paths in its observations are relative to it)."""
        from pathlib import Path

        return Path(self.images_dir) if self.images_dir is not None else self.store.campaign_images_dir(self.campaign_id)


def _num(x, nd: int = 2):
    return None if x is None or not math.isfinite(float(x)) else round(float(x), nd)


def heliostat_states(ids, verdicts, last, on_board, off_tracking, out_of_service) -> dict[str, str]:
    """Each heliostat's state on the map (pure): on a board, out of service or refused, needs
    attention, accepted, else waiting. ``last``: each heliostat's newest ended visit's outcome."""
    out = {}
    for hid in ids:
        verdict = verdicts.get(hid)
        if hid in on_board:
            out[hid] = "on-board"
        elif hid in out_of_service or last.get(hid) == "refused":
            out[hid] = "refused"
        elif hid in off_tracking or last.get(hid) == "fault":
            out[hid] = "attention"
        elif verdict is not None and verdict.accepted:
            out[hid] = "accepted"
        else:
            out[hid] = "waiting"
    return out


def _map(cfg, ids, states, src=None, width: int = 640, height: int = 420, pad: int = 24) -> dict:
    """SVG coordinates of the heliostats (east right, north up) and the tower. A field of more than
    :data:`MAP_SVG_MAX` heliostats is drawn on a canvas: ``canvas`` True, no ``points`` but
    ``codes``, one letter per heliostat of ``ids`` (its state's initial, ``-`` for one without a
    position); the positions are drawn once into the page (:func:`map_positions`)."""
    layout = map_layout(cfg, ids, src, width, height, pad)
    if not layout["available"]:
        return {"available": False, "points": [], "width": width, "height": height, "canvas": False}
    if len(ids) > MAP_SVG_MAX:
        codes = "".join(STATE_CODES[states[h]] if h in layout["xy"] else "-" for h in ids)
        return {"available": True, "canvas": True, "points": [], "codes": codes, "drawn": len(layout["xy"]),
                "width": width, "height": height, "r": layout["r"], "tower": layout["tower"]}
    points = [{"id": h, "state": states[h], "xy": layout["xy"][h]} for h in ids if h in layout["xy"]]
    return {"available": True, "canvas": False, "points": points, "width": width, "height": height,
            "r": layout["r"], "tower": layout["tower"]}


STATE_CODES = {"waiting": "w", "on-board": "o", "accepted": "a", "refused": "r", "attention": "t"}
"""A heliostat's state on the canvas map, one letter (console.js reads them back)."""


def map_layout(cfg, ids, src=None, width: int = 640, height: int = 420, pad: int = 24) -> dict:
    """Each heliostat's map coordinates (``xy``), the dot radius and the tower; computed once per
    :class:`Sources` (positions do not move)."""
    if src is not None and src.positions is not None:
        return src.positions
    pos = {h.id: h.position_enu_m for h in cfg.heliostats} if cfg is not None else {}
    have = [hid for hid in ids if hid in pos]
    tower = cfg.tower.receiver_aim_enu_m if cfg is not None else None
    if not have:
        return {"available": False}
    xs = [pos[h][0] for h in have] + ([tower[0]] if tower is not None else [])
    ys = [pos[h][1] for h in have] + ([tower[1]] if tower is not None else [])
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    scale = min((width - 2 * pad) / max(x1 - x0, 1.0), (height - 2 * pad) / max(y1 - y0, 1.0))

    def xy(e, n):
        return round(pad + (e - x0) * scale, 1), round(height - pad - (n - y0) * scale, 1)

    r = max(3.0, min(9.0, 0.45 * scale * _spacing(pos, have))) if len(have) <= MAP_SVG_MAX else \
        max(0.6, min(9.0, 0.45 * scale * _spacing(pos, have)))
    out = {"available": True, "xy": {h: xy(pos[h][0], pos[h][1]) for h in have}, "r": round(r, 2),
           "tower": None if tower is None else xy(tower[0], tower[1])}
    if src is not None:
        src.positions = out
    return out


def map_positions(src) -> dict:
    """The canvas map's static part, drawn once into the page: ids and x, y in the map's
    coordinates, in the order of the view's ``codes``."""
    ids = src.heliostat_ids()
    layout = map_layout(src.cfg, ids, src)
    if not layout.get("available"):
        return {"ids": [], "x": [], "y": []}
    xy = layout["xy"]
    return {"ids": ids, "x": [xy[h][0] if h in xy else None for h in ids],
            "y": [xy[h][1] if h in xy else None for h in ids]}


def _spacing(pos, ids) -> float:
    """A typical distance between neighbouring heliostats [m] (the median nearest-neighbour distance),
    from a k-d tree: O(n log n), tens of ms for 10⁴ heliostats (the map is drawn every refresh)."""
    import numpy as np
    from scipy.spatial import cKDTree

    p = np.array([pos[h][:2] for h in ids], dtype=float)
    if len(p) < 2:
        return 10.0
    d, _i = cKDTree(p).query(p, k=2)
    return float(np.median(d[:, 1]))


def _age(now_s, then_s):
    return None if now_s is None or then_s is None else max(0.0, float(now_s) - float(then_s))


def _reading_gate(cfg, wind_ms, dni_wm2, sun_elevation_deg, stowed: bool, fallback):
    """(open, night, reason) of the gate for one weather reading, as the controller decides it
    (:func:`helicalib.campaign.choice.field_gate`), so the banner and the figures beside it agree;
    ``fallback`` (open, night, reason) when there is no config or the sun is below the low band."""
    from types import SimpleNamespace

    from helicalib.campaign.choice import field_gate

    if cfg is None or sun_elevation_deg is None or sun_elevation_deg < cfg.acceptance.low_band_deg[0]:
        return fallback
    nan = float("nan")
    weather = None if wind_ms is None and dni_wm2 is None else SimpleNamespace(
        wind_ms=nan if wind_ms is None else float(wind_ms), dni_wm2=nan if dni_wm2 is None else float(dni_wm2))
    g = field_gate(cfg, weather, float(sun_elevation_deg), 0.0, None, stowed=stowed)
    return g.open, g.night, g.reason


def _gate(cfg, snapshot, events, last_obs, standing, now_s) -> dict:
    """The gate panel: the banner and every figure of it from ONE weather reading, with its time and
    age; the plant unreachable since when (the snapshot's, else the newest plant_lost/plant_back)."""
    from types import SimpleNamespace

    from helicalib.campaign.words import gate_text

    g = cfg.gating if cfg is not None else None
    limits = None if g is None else {"wind_max_ms": g.wind_max_ms, "stow_wind_ms": g.stow_wind_ms,
                                     "dni_min_wm2": g.dni_min_wm2, "cleanliness_min": g.cleanliness_min}
    changes = [e for e in events if e.kind in ("gated", "ungated")]
    logged = None if not changes else {"kind": changes[-1].kind, "reason": changes[-1].reason,
                                       "time_s": changes[-1].time_s}
    if snapshot is not None:
        wind, dni, time_s = snapshot.wind_ms, snapshot.dni_wm2, snapshot.weather_time_s
        stowed, unreachable = snapshot.stowed, snapshot.plant_unreachable_since_s
        open_, night, reason = _reading_gate(cfg, wind, dni, snapshot.sun_elevation_deg, stowed,
                                             (snapshot.gate_open, snapshot.night, snapshot.gate_reason))
        if wind is None and dni is None:
            open_ = None if open_ is False and not night else open_
        source = "controller"
    else:
        marks = [e for e in events if e.kind in ("stow", "resume")]
        stowed = bool(marks) and marks[-1].kind == "stow"
        lost = [e for e in events if e.kind in ("plant_lost", "plant_back")]
        unreachable = lost[-1].time_s if lost and lost[-1].kind == "plant_lost" else None
        obs = max(last_obs.values(), key=lambda o: o.capture_time_s, default=None)
        wind = None if obs is None else obs.wind_ms
        dni = None if obs is None else obs.dni_wm2
        time_s = None if obs is None else obs.capture_time_s
        el = None if obs is None else obs.sun_elevation_deg
        open_, night, reason = _reading_gate(cfg, wind, dni, el, stowed,
                                             (None, False, "no measurement recorded yet") if obs is None
                                             else (False, False, "no field config to judge the reading"))
        if obs is None:
            open_ = None
        source = "database"
    text = gate_text(SimpleNamespace(stowed=stowed, gate_open=open_, night=night, gate_reason=reason,
                                      plant_unreachable_since_s=None))  # the page says the loss itself
    return {"source": source, "wind_ms": _num(wind, 1), "dni_wm2": _num(dni, 0), "stowed": stowed, "text": text,
            "open": bool(open_) and not stowed and unreachable is None, "limits": limits, "paused": standing.paused,
            "night": night, "as_of_s": time_s, "age_s": _age(now_s, time_s),
            "unreachable_since_s": unreachable, "unreachable_s": _age(now_s, unreachable), "logged": logged}


def _frames_of(obs) -> dict:
    return {"id": int(obs.id), "visit_id": obs.visit_id, "iteration": int(obs.iteration), "target_id": obs.target_id,
            "before": obs.before_frame_path, "after": list(obs.after_frame_paths), "valid": bool(obs.valid),
            "reason": obs.reason, "error_mrad": _num(obs.error_mrad),
            "spot_px": None if obs.spot_x_px is None else [float(obs.spot_x_px), float(obs.spot_y_px)]}


def _boards(cfg, snapshot, running_visits, last_obs, framed, frames_cache, live_visits: bool, now_s) -> list[dict]:
    running = {v.target_id: v for v in running_visits} if live_visits else {}
    targets = [t.id for t in cfg.targets] if cfg is not None else sorted({v.target_id for v in running_visits}
                                                                         | set(last_obs))
    live = {b.target_id: b for b in snapshot.boards} if snapshot is not None else {}
    out = []
    for tid in targets:
        b = live.get(tid)
        v = running.get(tid)
        obs = last_obs.get(tid)
        if snapshot is not None:
            hid = b.heliostat_id if b is not None else None
            row = {"target": tid, "heliostat": hid, "iteration": None if b is None else b.iteration,
                   "last_error_mrad": None if b is None else _num(b.last_error_mrad), "since_s": None if b is None
                   else b.since_s}
        else:
            hid = v.heliostat_id if v is not None else None
            same = obs is not None and v is not None and obs.visit_id == v.id
            row = {"target": tid, "heliostat": hid, "iteration": obs.iteration if same else None,
                   "last_error_mrad": _num(obs.error_mrad) if same and obs.valid else None,
                   "since_s": None if v is None else v.started_s}
        f = framed.get(tid)
        if f is not None:
            frames_cache[int(f.id)] = _frames_of(f)
            for old in sorted(frames_cache)[:-FRAMES_KEPT]:
                frames_cache.pop(old, None)
            # the frames are labelled with the visit they belong to: the heliostat on the board
            # now, or an earlier one (a visit starts before its first frames are taken)
            this_visit = (hid is not None and f.heliostat_id == hid
                          and (row["since_s"] is None or f.capture_time_s >= row["since_s"] - 1.0))
            row["frames"] = {"id": int(f.id), "heliostat": f.heliostat_id, "iteration": int(f.iteration),
                             "time_s": f.capture_time_s, "age_s": _age(now_s, f.capture_time_s),
                             "valid": bool(f.valid), "reason": f.reason, "error_mrad": _num(f.error_mrad),
                             "this_visit": this_visit, "cleanliness": _num(f.cleanliness),
                             "cleanliness_measured": _num(getattr(f, "cleanliness_measured", None))}
        else:
            row["frames"] = None
        row["since_age_s"] = _age(now_s, row["since_s"])
        out.append(row)
    return out


def _bands(cfg, now_s: float, ids, verdicts, states) -> dict:
    """Today's rising and setting low bands and high windows, each with the heliostats that still need it."""
    from helicalib.calibration.sun_days import n_high_windows, sun_days

    if cfg is None:
        return {"available": False, "rows": []}
    acc = cfg.acceptance
    key = (id(cfg), int(now_s // 600.0))  # the day's bands move by seconds a day: recomputed every 10 min
    if _DAYS.get("key") != key:
        _DAYS.update(key=key, days=sun_days(cfg.site, now_s - 86400.0, now_s + 86400.0, acc.low_band_deg,
                                            acc.high_elevation_deg, step_s=300.0))
    days = _DAYS["days"]
    today = min(days, key=lambda d: abs(d.noon_s - now_s), default=None)
    if today is None:
        return {"available": False, "rows": []}
    todo = [h for h in ids if states.get(h) not in ("accepted", "refused")]

    def need(key) -> int:
        return sum(1 for h in todo if not ((verdicts.get(h).details if verdicts.get(h) else {}) or {}).get(key))

    rows = []
    for name, key, a, b in (("rising band", "rising_ok", today.rise_band_start_s, today.rise_band_end_s),
                            ("setting band", "setting_ok", today.set_band_start_s, today.set_band_end_s)):
        rows.append({"name": name, "start_s": a, "end_s": b, "need": need(key), "state": _when(a, b, now_s)})
    if today.high_start_s is not None:
        n_win = n_high_windows(today.high_span_s, acc.high_window_h)
        for k in range(n_win):
            a, b = today.high_window(k, n_win)
            missing = sum(1 for h in todo if not _window_done(verdicts.get(h), k))
            rows.append({"name": f"high window {k + 1}", "start_s": a, "end_s": b, "need": missing,
                         "state": _when(a, b, now_s)})
    return {"available": True, "rows": rows, "open": [r for r in rows if r["state"] != "passed"]}


def _window_done(verdict, k: int) -> bool:
    counts = ((verdict.details or {}).get("window_counts") if verdict is not None else None) or []
    return k < len(counts) and bool(counts[k])


def _when(a, b, now_s: float) -> str:
    if a is None or b is None:
        return "none today"
    return "passed" if b <= now_s else ("open now" if a <= now_s else "later today")


def log_rows(events, visits, limit: int = EVENTS_SHOWN) -> list[dict]:
    """The event log, newest first: the stored events and each ended visit (``visit_end``, from the
    visits table, so the log reads the same live and from the database alone)."""
    rows = [{"time_s": e.time_s, "kind": e.kind, "heliostat": e.heliostat_id, "reason": e.reason}
            for e in events[-limit:]]
    for v in visits[-limit:]:
        if v.outcome == "running" or v.ended_s is None:
            continue
        errs = "" if v.first_error_mrad is None else (
            f", {v.first_error_mrad:.2f} mrad" if v.final_error_mrad is None or v.iterations <= 1 else
            f", {v.first_error_mrad:.2f} -> {v.final_error_mrad:.2f} mrad in {v.iterations} placements")
        rows.append({"time_s": v.ended_s, "kind": "visit_end", "heliostat": v.heliostat_id,
                     "reason": f"{v.heliostat_id} off {v.target_id}: {v.outcome} ({v.reason}){errs}"})
    rows.sort(key=lambda r: r["time_s"], reverse=True)
    return rows[:limit]


# ---------------------------------------------------------------------------------------------- damage
RAW_ERRORS = (sqlite3.DatabaseError, json.JSONDecodeError)
"""What damaged data raises past the store's own checks (which raise :class:`DataError` naming the
table and row): a damaged page (``sqlite3.DatabaseError``) or JSON parsed outside the store. Any
other exception is a bug of the console, not damage, and is not dressed up as one."""


@contextmanager
def reading(store, campaign_id: int | None):
    """Turn a raw error while reading the database into one :class:`DataError` line naming the
    table and row (:func:`locate_damage`); helicalib's own errors pass as they are."""
    try:
        yield
    except HelicalibError:
        raise
    except RAW_ERRORS as err:
        raise DataError(damage_line(store, campaign_id, err)) from None


def damage_line(store, campaign_id: int | None, err: BaseException) -> str:
    """One line saying what in ``store`` could not be read: the damaged table and row when found."""
    said = " ".join(str(err).split())[:160]
    try:
        where = locate_damage(store, campaign_id)
    except (sqlite3.DatabaseError, ValueError) as again:
        where = None
        said = " ".join(str(again).split())[:160]
    path = getattr(store, "path", "the database")
    if where is not None:
        return f"{path}: damaged data in {where}; the console shows the rest once it is mended"
    return (f"{path}: the database could not be read ({type(err).__name__}: {said}); "
            "`sqlite3 DB 'PRAGMA integrity_check'` says where it is damaged")


def locate_damage(store, campaign_id: int | None) -> str | None:
    """The first damaged value of the campaign's rows, ``table T, row N: COLUMN is not ...`` (a
    ``*_json`` column that is not JSON, a REAL or INTEGER column holding text or bytes), or None."""
    tables = [r[0] for r in store._read("SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE "
                                        "'sqlite_%' ORDER BY name")]
    for table in tables:
        cols = store._read(f'PRAGMA table_info("{table}")')
        names = [c["name"] for c in cols]
        key = "campaign_id" if "campaign_id" in names else ("id" if table == "campaigns" else None)
        where = "" if campaign_id is None or key is None else f" AND {key} = {int(campaign_id)}"
        for c in cols:
            word = {"REAL": "a number", "INTEGER": "an integer"}.get(str(c["type"]).upper())
            if word is None:
                continue
            bad = store._read(f'SELECT rowid, "{c["name"]}" FROM "{table}" WHERE typeof("{c["name"]}") NOT IN '
                              f"('real', 'integer', 'null'){where} LIMIT 1")
            if bad:
                value = bad[0][1]
                return f"table {table}, row {bad[0][0]}: {c['name']} is not {word} ({type(value).__name__} {value!r:.40})"
        for col in (n for n in names if n.endswith("_json")):
            for rowid, text in store._read(f'SELECT rowid, "{col}" FROM "{table}" WHERE 1{where}'):
                try:
                    json.loads(text)
                except (ValueError, TypeError, RecursionError):
                    return f"table {table}, row {rowid}: {col} is not JSON ({text!r:.40})"
    return None


def read_view(src: Sources, snapshot=None) -> dict:
    """Everything the page shows (see the module's docstring); ``snapshot``: the controller's newest."""
    from helicalib.store.history import replay

    store, cfg, cid = src.store, src.cfg, src.campaign_id
    campaign = store.campaign(cid)
    ids = src.heliostat_ids()
    verdicts = src.latest_verdicts()
    running = store.visits(cid, outcome="running")
    recent = store.visits(cid, newest=EVENTS_SHOWN)
    events = store.events(cid, kinds=STATE_EVENT_KINDS)  # the gate's, the plant's and the tracking's: few
    log = store.events(cid, newest=EVENTS_SHOWN, data=False)
    actions = store.actions(cid)
    standing = replay(actions)
    last_obs = store.latest_by_target(cid)
    framed = store.latest_by_target(cid, with_frames=True)
    from helicalib.store.records import off_tracking

    off = set(snapshot.off_tracking) if snapshot is not None else set(off_tracking(events))
    if snapshot is not None:
        on_board = {b.heliostat_id for b in snapshot.boards if b.heliostat_id}
    else:
        on_board = {v.heliostat_id for v in running} if campaign.status == "running" else set()
    states = heliostat_states(ids, verdicts, store.last_outcomes(cid), on_board, off, standing.out_of_service)
    times = [campaign.started_s] + [e.time_s for e in log[-1:]] + [o.capture_time_s for o in last_obs.values()]
    times += [v.started_s for v in recent[-1:]]
    now = snapshot.time_s if snapshot is not None else max(times)
    counts = {k: 0 for k in STATES}
    for st in states.values():
        counts[st] += 1
    pending = [a for a in actions if a.done_s is None]
    return {
        "campaign": {"id": campaign.id, "name": campaign.name, "mode": campaign.mode, "status": campaign.status,
                     "owner": store.owner()},
        "clock": {"time_s": now, "source": "plant" if snapshot is not None else "newest record",
                  "rate": None if snapshot is None else snapshot.rate, "armed": None if snapshot is None
                  else snapshot.armed},
        "gate": _gate(cfg, snapshot, events, last_obs, standing, now),
        "boards": _boards(cfg, snapshot, running, last_obs, framed, src.frames, campaign.status == "running", now),
        "map": _map(cfg, ids, states, src),
        "states": states,
        "counts": counts,
        "progress": {"heliostats": len(ids), "accepted": counts["accepted"],
                     "next_band": None if snapshot is None else snapshot.next_band,
                     "started_s": campaign.started_s, "plot": now - campaign.started_s >= PLOT_AFTER_S,
                     "visits": store.count_visits(cid), "bands": _bands(cfg, now, ids, verdicts, states)},
        "events": log_rows(log, recent),
        "kinds": sorted(set(store.event_kinds(cid)) | ({"visit_end"} if recent else set())),
        "actions": [{"id": a.id, "kind": a.kind, "heliostats": list(a.heliostat_ids), "who": a.who,
                     "requested_wall_s": a.requested_wall_s, "requested_s": a.requested_s, "done_s": a.done_s,
                     "outcome": a.outcome}
                    for a in reversed(actions[-20:])],
        "pending": len(pending),
        "paused": standing.paused,
        "out_of_service": sorted(standing.out_of_service),
        "armed_actions": src.armed_actions,
    }
