"""Benchmark splits of an observation set into train and test, after PAINT's calibration benchmarks.

PAINT (``paint.data.dataset_splits.DatasetSplitter``) splits one heliostat's calibration records three
ways (train / validation / test) by the sun's position; helicalib needs two (fit on *train*, predict
*test*), so PAINT's *validation* set, the hard one, is our test set and everything else is train:

``azimuth``
    PAINT: train = the records of smallest sun azimuth (PAINT's azimuth: 0 = south, +90 = east, so
    these are the afternoon ones), validation = the largest (morning). Here: test = the ``n_test``
    records of largest PAINT azimuth, train = the rest. Ties: the earlier index first.
``solstice``
    PAINT: train = closest in time to the winter solstice, validation = closest to the summer
    solstice. Here: test = the ``n_test`` records of highest solar *declination* (the sun's
    season, ``asin(s · polar axis)``), train = the rest. Declination is the distance to the June
    solstice written in the sun's own position (23.44° cos(2π Δt / year)), so it works for records
    without a time stamp, as PAINT's own JSON records are.
``balanced``
    PAINT: k-means over (azimuth, elevation) with as many clusters as validation records, one
    random record per cluster to validation and one to test, clusters too small filled at random.
    Here: ``n_test`` clusters (scipy's k-means++, seeded), one random member of each to test,
    empty clusters filled at random from the rest; train = the rest.
``high-variance``
    PAINT: the mean distance in (azimuth°, elevation°) to the 3 nearest other records; the most
    isolated go to validation. Here: test = the ``n_test`` most isolated, train = the rest.

``n_test = round(test_share · n)``, at least 1 and at most ``n - 1``. Every split is a pure
function of the sun positions (and the seed for ``balanced``): reproducible, train and test
disjoint and together the whole set.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from helicalib.errors import MeasurementError

SPLITS: tuple[str, ...] = ("azimuth", "solstice", "balanced", "high-variance")
DEFAULT_TEST_SHARE = 0.3
HIGH_VARIANCE_NEIGHBOURS = 3  # PAINT's n_neighbors


@dataclass(frozen=True)
class Split:
    """Indices into the observation set: ``train`` and ``test`` (sorted, disjoint, together all)."""

    kind: str
    train: np.ndarray
    test: np.ndarray


def n_test_of(n: int, test_share: float) -> int:
    """How many of ``n`` observations go to test: ``round(test_share · n)`` within [1, n - 1]."""
    if not (0.0 < test_share < 1.0):
        raise MeasurementError(f"test share {test_share}: expected a number between 0 and 1")
    if n < 2:
        raise MeasurementError(f"{n} observation(s): a split needs at least 2")
    return int(min(max(round(test_share * n), 1), n - 1))


def paint_azimuth_elevation_deg(sun_enu) -> tuple[np.ndarray, np.ndarray]:
    """Unit sun vectors (K, 3) → PAINT's azimuth (0 = south, +90 = east) and elevation [deg]."""
    s = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    return (np.degrees(np.arctan2(s[:, 0], -s[:, 1])),
            np.degrees(np.arctan2(s[:, 2], np.hypot(s[:, 0], s[:, 1]))))


def declination_deg(sun_enu, latitude_deg: float) -> np.ndarray:
    """Solar declination [deg] from unit sun vectors (K, 3) at a site: the angle of the sun above the
    celestial equator, ``asin(s · (0, cos φ, sin φ))`` (the Earth's axis in local ENU)."""
    s = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    phi = np.radians(latitude_deg)
    return np.degrees(np.arcsin(np.clip(s[:, 1] * np.cos(phi) + s[:, 2] * np.sin(phi), -1.0, 1.0)))


def _top(score: np.ndarray, n_test: int) -> np.ndarray:
    """Indices of the ``n_test`` largest scores; equal scores: the earlier index first."""
    order = np.lexsort((np.arange(len(score)), -score))
    return order[:n_test]


def _split(kind: str, n: int, test) -> Split:
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(test, dtype=int)] = True
    return Split(kind, np.flatnonzero(~mask), np.flatnonzero(mask))


def azimuth_split(azimuth_deg, test_share: float = DEFAULT_TEST_SHARE) -> Split:
    """Test = the largest PAINT azimuths (morning, east), train = the rest."""
    az = np.asarray(azimuth_deg, dtype=float)
    return _split("azimuth", len(az), _top(az, n_test_of(len(az), test_share)))


def solstice_split(declination, test_share: float = DEFAULT_TEST_SHARE) -> Split:
    """Test = the highest declinations (nearest the June solstice), train = the rest."""
    dec = np.asarray(declination, dtype=float)
    return _split("solstice", len(dec), _top(dec, n_test_of(len(dec), test_share)))


def balanced_split(azimuth_deg, elevation_deg, test_share: float = DEFAULT_TEST_SHARE, seed: int = 0) -> Split:
    """k-means (k = n_test) over (azimuth°, elevation°); one random member of each cluster to test."""
    from scipy.cluster.vq import kmeans2

    x = np.column_stack([np.asarray(azimuth_deg, float), np.asarray(elevation_deg, float)])
    n = len(x)
    k = n_test_of(n, test_share)
    rng = np.random.default_rng(seed)
    if len(np.unique(x, axis=0)) <= k:  # too few distinct positions to cluster: every point its own cluster
        labels = np.unique(x, axis=0, return_inverse=True)[1].ravel()
    else:
        with warnings.catch_warnings():  # an empty cluster is handled below
            warnings.simplefilter("ignore", UserWarning)
            _, labels = kmeans2(x, k, minit="++", missing="warn", rng=rng)
    test = [int(rng.choice(np.flatnonzero(labels == c))) for c in np.unique(labels)][:k]
    if len(test) < k:  # empty clusters: fill at random from the rest, as PAINT does
        rest = np.setdiff1d(np.arange(n), test)
        test += rng.choice(rest, size=k - len(test), replace=False).tolist()
    return _split("balanced", n, test)


def high_variance_split(azimuth_deg, elevation_deg, test_share: float = DEFAULT_TEST_SHARE,
                        neighbours: int = HIGH_VARIANCE_NEIGHBOURS) -> Split:
    """Test = the sun positions farthest on average from their nearest neighbours; train = the rest."""
    from scipy.spatial import cKDTree

    x = np.column_stack([np.asarray(azimuth_deg, float), np.asarray(elevation_deg, float)])
    n = len(x)
    k = n_test_of(n, test_share)
    m = min(neighbours, n - 1)
    dist, _ = cKDTree(x).query(x, k=m + 1)
    score = np.asarray(dist, dtype=float).reshape(n, -1)[:, 1:].mean(axis=1)
    return _split("high-variance", n, _top(score, k))


def make_split(kind: str, sun_enu, latitude_deg: float, test_share: float = DEFAULT_TEST_SHARE,
               seed: int = 0) -> Split:
    """One of :data:`SPLITS` over unit sun vectors (K, 3) seen from a site at ``latitude_deg``."""
    az, el = paint_azimuth_elevation_deg(sun_enu)
    if kind == "azimuth":
        return azimuth_split(az, test_share)
    if kind == "solstice":
        return solstice_split(declination_deg(sun_enu, latitude_deg), test_share)
    if kind == "balanced":
        return balanced_split(az, el, test_share, seed)
    if kind == "high-variance":
        return high_variance_split(az, el, test_share)
    raise MeasurementError(f"split {kind!r}: unknown; known: {', '.join(SPLITS)}")
