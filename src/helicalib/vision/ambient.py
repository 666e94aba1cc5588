"""Is the ambient light ratio of a spot measurement taken on the free board? (pure numpy)

:func:`helicalib.vision.spot.measure_spot` subtracts ``k`` times the before frame from the after frame,
``k`` the after/before light ratio of the board free of the spot. A spot that covers nearly all of the
board leaves it a rim too narrow for the ratio's mode, and ``k`` is then taken on the spot itself
(where other light in the before frame keeps the ratio low): the difference loses part of the spot and
its centre lands metres off. A beam only adds light, so with the right ``k`` hardly a cell of the board
is darker in the after frame than ``k`` times the before frame; with ``k`` taken on the spot the free
board and the spot's fainter parts all are. :func:`below_share` counts them against the sensor's own
noise (:func:`sensor_noise`), which, unlike the spread of the cells at ``k``, does not grow with a
wrong ``k``.
"""

from __future__ import annotations

import math

import numpy as np

BELOW_SIGMAS = 3.0
"""Cells darker than the ambient fit by more than this many sensor noise sigmas count in :func:`below_share`."""


def mad_sigma(x: np.ndarray) -> float:
    """A Gaussian sigma from the median absolute deviation, at least 0.5 grey levels."""
    return max(0.5, 1.4826 * float(np.median(np.abs(x - np.median(x)))))


def sensor_noise(d: np.ndarray, lit: np.ndarray) -> float:
    """The noise sigma of ``d`` (2-D) from second differences of neighbouring cells along both axes, all
    three cells in ``lit``: smooth light, a gradient and a spot's slope cancel, the sensor noise stays,
    whatever ratio ``d`` was formed with. NaN with fewer than 16 such triples."""
    parts = []
    for x, m in ((d, lit), (d.T, lit.T)):
        both = m[:, :-2] & m[:, 1:-1] & m[:, 2:]
        parts.append((x[:, :-2] - 2.0 * x[:, 1:-1] + x[:, 2:])[both])
    dd = np.concatenate(parts)
    return mad_sigma(dd) / math.sqrt(6.0) if dd.size >= 16 else float("nan")


def below_share(a_s: np.ndarray, b_s: np.ndarray, lit: np.ndarray, k: float) -> float:
    """The share of the ``lit`` cells darker in the after frame ``a_s`` than ``k`` times the before frame
    ``b_s`` by more than :data:`BELOW_SIGMAS` sensor noise sigmas (2-D float arrays on one grid).

    Near 0 (the noise's tail) when ``k`` is the free board's ratio; a large share when ``k`` was taken
    on a spot that covers nearly all of the board, or when a beam lay on the board in the before frame
    only (which the spot measurement tells by its lost-light test first). 0 without lit cells or noise.
    """
    d = a_s - k * b_s
    floor = sensor_noise(d, lit)
    n = int(np.count_nonzero(lit))
    if not n or not floor > 0:
        return 0.0
    return float(np.count_nonzero(lit & (d < -BELOW_SIGMAS * floor))) / n
