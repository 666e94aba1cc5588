"""Deterministic, random-access noise: the same (seed, stream, key) always gives the same number.

The simulated plant must give the same weather and the same jitter for a given plant time no
matter in which order or how often it is asked, so it does not draw from a stateful generator;
it hashes integer keys (splitmix64) into uniform and normal variates instead. All functions are
vectorised over numpy integer arrays.
"""

from __future__ import annotations

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_TWO53 = float(2**53)


_S30, _S27, _S31 = np.uint64(30), np.uint64(27), np.uint64(31)
_add, _mul, _xor, _shr = np.add, np.multiply, np.bitwise_xor, np.right_shift


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser on uint64 arrays (wrapping arithmetic). Written as ufunc calls: they
    wrap silently on numpy scalars too, so no ``errstate`` is entered per call (the same bits)."""
    z = _add(x, _GOLDEN)
    z = _mul(_xor(z, _shr(z, _S30)), _M1)
    z = _mul(_xor(z, _shr(z, _S27)), _M2)
    return _xor(z, _shr(z, _S31))


_HEADS: dict[tuple[int, int], np.ndarray] = {}


def _head(seed: int, stream: int) -> np.ndarray:
    """The mixed (seed, stream) that every hash of the stream starts from (remembered)."""
    key = (seed, stream)
    h = _HEADS.get(key)
    if h is None:
        if len(_HEADS) >= 1024:
            _HEADS.clear()
        h = _HEADS[key] = np.asarray(
            _mix(np.uint64(seed & 0xFFFFFFFFFFFFFFFF) ^ (np.uint64(stream & 0xFFFFFFFF) << np.uint64(32))),
            dtype=np.uint64)
    return h


def hash_keys(seed: int, stream: int, *keys) -> np.ndarray:
    """uint64 hash of (seed, stream, keys...) broadcast over the key arrays."""
    h = _head(int(seed), int(stream))
    if not keys:
        return h.copy()
    for k in keys:
        a = np.asarray(k)
        a = a.astype(np.int64).view(np.uint64) if a.dtype.kind == "i" else np.asarray(a, dtype=np.uint64)
        h = _mix(_xor(h, _mix(a)))
    return h


def uniform(seed: int, stream: int, *keys) -> np.ndarray:
    """Uniform variates in (0, 1), one per broadcast key."""
    return _unit_interval(hash_keys(seed, stream, *keys))


_LAST_01 = _mix(np.array([0, 1], dtype=np.uint64))
"""The mixed last keys 0 and 1 of :func:`normal`'s two uniforms."""


def _unit_interval(h: np.ndarray) -> np.ndarray:
    return ((h >> np.uint64(11)).astype(np.float64) + 0.5) / _TWO53


def normal(seed: int, stream: int, *keys) -> np.ndarray:
    """Standard normal variates (Box–Muller on two hashed uniforms, ``uniform(..., *keys, 0)`` and
    ``uniform(..., *keys, 1)``), one per broadcast key. The keys' hash is taken once for both."""
    h = hash_keys(seed, stream, *keys)[..., None]
    u = _unit_interval(_mix(h ^ _LAST_01))
    return np.sqrt(-2.0 * np.log(u[..., 0])) * np.cos(2.0 * np.pi * u[..., 1])


def smooth_normal(seed: int, stream: int, t_s, correlation_s: float, *keys) -> np.ndarray:
    """A smooth, zero-mean, unit-variance random process of time, evaluated at ``t_s``.

    Independent normal values sit on knots every ``correlation_s`` seconds and are joined by a
    cosine interpolation rescaled to keep the variance 1 between knots. ``keys`` (e.g. a heliostat
    index array) select independent processes. Shape: broadcast of ``t_s`` and ``keys``.
    """
    x = np.asarray(t_s, dtype=float) / float(correlation_s)
    k0 = np.floor(x)
    f = x - k0
    w = 0.5 - 0.5 * np.cos(np.pi * f)
    if not keys and k0.ndim == 0:  # one process at one time (the weather): its knots are remembered
        a, b = _knot(seed, stream, int(k0)), _knot(seed, stream, int(k0) + 1)
    else:
        a = normal(seed, stream, k0.astype(np.int64), *keys)
        b = normal(seed, stream, (k0 + 1).astype(np.int64), *keys)
    return ((1.0 - w) * a + w * b) / np.sqrt((1.0 - w) ** 2 + w**2)


_KNOTS: dict[tuple[int, int, int], float] = {}
_KNOTS_MAX = 4096


def _knot(seed: int, stream: int, k: int) -> float:
    """``normal(seed, stream, k)`` for one knot, remembered (the same value; a pure function of its key)."""
    key = (seed, stream, k)
    v = _KNOTS.get(key)
    if v is None:
        if len(_KNOTS) >= _KNOTS_MAX:
            _KNOTS.clear()
        v = _KNOTS[key] = float(normal(seed, stream, np.int64(k)))
    return v
