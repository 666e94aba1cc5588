"""Compile helicalib's numba kernels once (or load them from numba's cache): ``python -m helicalib.warm``.

The compiled hot path (:mod:`helicalib.geometry.kernels`, :mod:`helicalib.calibration.fit_kernels`)
is cached on disk beside its source (``cache=True``); the Makefile runs this module before
``make demo`` and ``make test`` so that no run, and no test worker, pays the first compile. From
the cache it takes well under a second.
"""

from __future__ import annotations

import time


def warm() -> dict[str, float]:
    """Compile or load every kernel; seconds per module and in all."""
    from helicalib.calibration import fit_kernels
    from helicalib.geometry import kernels

    t0 = time.perf_counter()
    kernels.warm()
    t1 = time.perf_counter()
    fit_kernels.warm()
    t2 = time.perf_counter()
    return {"geometry_s": t1 - t0, "fit_s": t2 - t1, "total_s": t2 - t0}


if __name__ == "__main__":
    s = warm()
    print(f"helicalib kernels ready in {s['total_s']:.1f} s (geometry {s['geometry_s']:.1f} s, fit {s['fit_s']:.1f} s)")
