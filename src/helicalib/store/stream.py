"""Read a campaign's observations in bounded chunks: a reader of a 10⁴-heliostat campaign that never
holds all its rows at once.

>>> with Store.open("campaign.db", readonly=True) as store:
...     for hid, rows in iter_heliostat_observations(store, campaign_id, valid=True):
...         write_files(hid, rows)          # one heliostat at a time

Each chunk is one query under the store's lock (:meth:`Store._read`: rows checked against the
schema, damaged pages named in one line), paged by key (``(heliostat_id, id) > (last)``) rather
than by a cursor held open between chunks, so other readers of the same store run between two
chunks and a reader beside a running campaign sees each chunk whole. Open the store with
``readonly=True`` beside a running campaign.
"""

from __future__ import annotations

from collections.abc import Iterator

from helicalib.store.observation_rows import observation_from_row
from helicalib.store.records import Observation

DEFAULT_CHUNK = 5000
"""Rows per query: a few MB of Observation objects."""

ORDERS = {"heliostat": ("heliostat_id", "id"), "id": ("id",)}
"""Orders a stream can take: by heliostat (then recording order), or recording order."""


def _query(campaign_id: int, order: str, valid: bool | None, after: tuple | None, chunk: int) -> tuple[str, tuple]:
    keys = ORDERS[order]
    where, params = ["campaign_id = ?"], [int(campaign_id)]
    if valid is not None:
        where.append("valid = ?")
        params.append(int(bool(valid)))
    if after is not None:
        where.append(f"({', '.join(keys)}) > ({', '.join('?' for _ in keys)})")
        params += list(after)
    sql = f"SELECT * FROM observations WHERE {' AND '.join(where)} ORDER BY {', '.join(keys)} LIMIT ?"
    return sql, (*params, int(chunk))


def iter_observation_chunks(store, campaign_id: int, *, chunk: int = DEFAULT_CHUNK, order: str = "heliostat",
                            valid: bool | None = None) -> Iterator[list[Observation]]:
    """The campaign's observations (``valid``: only valid or only invalid ones), ``chunk`` rows per list,
    in ``order`` (``"heliostat"``: by heliostat id then recording order; ``"id"``: recording order)."""
    if order not in ORDERS:
        raise ValueError(f"order {order!r}: expected one of {', '.join(ORDERS)}")
    if chunk < 1:
        raise ValueError(f"chunk {chunk}: expected at least 1 row")
    keys, after = ORDERS[order], None
    while True:
        sql, params = _query(campaign_id, order, valid, after, chunk)
        rows = store._read(sql, params, table="observations")
        if not rows:
            return
        yield [observation_from_row(r, store.path) for r in rows]
        if len(rows) < chunk:
            return
        after = tuple(rows[-1][k] for k in keys)


def iter_observations(store, campaign_id: int, *, chunk: int = DEFAULT_CHUNK, order: str = "heliostat",
                      valid: bool | None = None) -> Iterator[Observation]:
    """The same stream as :func:`iter_observation_chunks`, one observation at a time."""
    for rows in iter_observation_chunks(store, campaign_id, chunk=chunk, order=order, valid=valid):
        yield from rows


def iter_heliostat_observations(store, campaign_id: int, *, chunk: int = DEFAULT_CHUNK,
                                valid: bool | None = None) -> Iterator[tuple[str, list[Observation]]]:
    """(heliostat id, its observations in recording order), heliostat by heliostat in id order: at most
    one heliostat's rows and one chunk in memory."""
    current, rows = None, []
    for obs in iter_observations(store, campaign_id, chunk=chunk, order="heliostat", valid=valid):
        if obs.heliostat_id != current:
            if rows:
                yield current, rows
            current, rows = obs.heliostat_id, []
        rows.append(obs)
    if rows:
        yield current, rows


def fit_row(o: Observation, spot_method: str = "grlm-centroid"):
    """A valid observation as a fit-input row (:class:`helicalib.calibration.observations.Observation`, the
    row :meth:`Store.export_fit_csv` writes), or None when it has no located spot: read-back strokes
    (commanded when none was read), offsets from the aim point, the row id as ``record_id``."""
    import pandas as pd

    from helicalib.calibration.observations import Observation as FitRow

    if o.spot_enu_m is None or o.offset_u_m is None or o.offset_v_m is None:
        return None
    strokes = o.strokes_read_mm or o.strokes_cmd_mm
    when = pd.Timestamp(o.capture_time_s, unit="s", tz="UTC").isoformat()
    return FitRow(heliostat_id=o.heliostat_id, utc_time=when, sun_e=o.sun_enu[0], sun_n=o.sun_enu[1],
                  sun_u=o.sun_enu[2], stroke1_mm=strokes[0], stroke2_mm=strokes[1], target_id=o.target_id,
                  spot_e_m=o.spot_enu_m[0], spot_n_m=o.spot_enu_m[1], spot_u_m=o.spot_enu_m[2],
                  target_u_m=o.offset_u_m, target_v_m=o.offset_v_m, spot_method=spot_method,
                  source="campaign", record_id=str(o.id))
