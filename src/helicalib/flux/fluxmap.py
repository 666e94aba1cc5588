"""Flux density maps on the board grid: E = F_e·G (paper eqs. 1 and 9), their figures and plots.

:func:`flux_map` turns a corrected grey-level map on the board grid into a :class:`FluxMap` with
the figures a crew asks for: peak flux and where it is, the power on the board (Σ E·ΔA) and the
flux-weighted centre. :func:`plot_flux_map` draws the seed's figures 7 (3-D surface) and 8
(colour map) side by side into one PNG.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from helicalib.flux.grid import BoardGrid

__all__ = ["FluxMap", "flux_map", "plot_flux_map"]


@dataclass(frozen=True)
class FluxMap:
    """A flux density map on the board and its figures.

    Attributes
    ----------
    flux_wm2 : np.ndarray, shape grid.shape
        Flux density on the board [W/m²]; NaN where the board was not seen.
    grid : BoardGrid
    peak_wm2 : float
        Largest flux density [W/m²].
    peak_uv_m : (float, float)
        Cell where it occurs [m, target frame].
    power_w : float
        Power on the board, Σ E·ΔA over the seen cells [W]. Negative noise is kept (unbiased).
    centre_uv_m : (float, float)
        Flux-weighted centre, Σ E·(u, v) / Σ E over the cells with E >= ``centre_threshold`` × peak
        [m, target frame]. The threshold keeps the board-wide noise (whose positive part would pull
        the centre toward the board centre) out of the sum.
    seen_fraction : float
        Fraction of the grid's cells that were inside the frame.
    """

    flux_wm2: np.ndarray
    grid: BoardGrid
    peak_wm2: float
    peak_uv_m: tuple[float, float]
    power_w: float
    centre_uv_m: tuple[float, float]
    seen_fraction: float

    def summary(self) -> dict:
        """Plain-data figures (no map) for JSON."""
        return {
            "peak_wm2": round(self.peak_wm2, 3),
            "peak_uv_m": [round(x, 4) for x in self.peak_uv_m],
            "power_w": round(self.power_w, 2),
            "centre_uv_m": [round(x, 4) for x in self.centre_uv_m],
            "grid_cell_m": round(self.grid.cell_m, 5),
            "grid_shape": list(self.grid.shape),
            "seen_fraction": round(self.seen_fraction, 4),
        }


def flux_map(grey_map: np.ndarray, grid: BoardGrid, fe_wm2_per_grey: float,
             factor: np.ndarray | float = 1.0, centre_threshold: float = 0.05) -> FluxMap:
    """``E = F_e · a · G`` on the board grid and its figures.

    Parameters
    ----------
    grey_map : np.ndarray, shape grid.shape
        Corrected (dark-free, linearised, flat-fielded, rectified) grey levels of the beam alone,
        i.e. the after − before difference [grey]. NaN marks unseen cells.
    grid : BoardGrid
    fe_wm2_per_grey : float
        Calibration factor F_e [W/m² per grey level].
    factor : float or np.ndarray of shape grid.shape
        Further per-cell factors, e.g. the non-Lambertian ``a_LB`` [-].
    centre_threshold : float
        Cells below this fraction of the peak do not count in the flux-weighted centre.

    Returns
    -------
    FluxMap
    """
    g = np.asarray(grey_map, dtype=float)
    if g.shape != grid.shape:
        raise ValueError(f"grey map shape {g.shape} does not match the grid {grid.shape}")
    flux = float(fe_wm2_per_grey) * np.asarray(factor, dtype=float) * g
    seen = np.isfinite(flux)
    if not seen.any():
        raise ValueError("no cell of the board was seen")
    uu, vv = grid.mesh_m()
    filled = np.where(seen, flux, -np.inf)
    k = np.unravel_index(int(np.argmax(filled)), flux.shape)
    peak = float(flux[k])
    positive = np.where(seen & (flux >= centre_threshold * peak) & (flux > 0), flux, 0.0)
    total = float(positive.sum())
    if total > 0:
        centre = (float((positive * uu).sum() / total), float((positive * vv).sum() / total))
    else:
        centre = (float("nan"), float("nan"))
    return FluxMap(
        flux_wm2=flux,
        grid=grid,
        peak_wm2=peak,
        peak_uv_m=(float(uu[k]), float(vv[k])),
        power_w=float(np.nansum(flux) * grid.cell_area_m2),
        centre_uv_m=centre,
        seen_fraction=float(seen.mean()),
    )


def plot_flux_map(fm: FluxMap, path: str | Path, title: str | None = None, max_surface_cells: int = 120) -> Path:
    """Write the 3-D surface (seed fig. 7) and colour map (seed fig. 8) of a flux map to a PNG.

    Parameters
    ----------
    fm : FluxMap
    path : str or Path
        Output PNG.
    title : str, optional
        Figure title.
    max_surface_cells : int
        The surface is decimated to at most this many cells per side (drawing speed only).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kw = fm.flux_wm2 / 1000.0
    fig = plt.figure(figsize=(13, 5.6))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    step = max(1, int(np.ceil(max(kw.shape) / max_surface_cells)))
    uu, vv = fm.grid.mesh_m()
    z = np.nan_to_num(kw[::step, ::step], nan=0.0)
    surf = ax3.plot_surface(uu[::step, ::step], vv[::step, ::step], z, cmap="jet", linewidth=0, antialiased=False)
    ax3.set_xlabel("u [m]")
    ax3.set_ylabel("v [m]")
    ax3.set_zlabel("flux [kW/m²]")
    ax3.set_title("flux density, 3-D")
    fig.colorbar(surf, ax=ax3, shrink=0.6, pad=0.1, label="kW/m²")
    ax2 = fig.add_subplot(1, 2, 2)
    im = ax2.imshow(kw, extent=fm.grid.extent_m, origin="upper", cmap="jet", interpolation="nearest")
    ax2.plot([fm.centre_uv_m[0]], [fm.centre_uv_m[1]], "w+", markersize=14, mew=2, label="flux-weighted centre")
    ax2.plot([fm.peak_uv_m[0]], [fm.peak_uv_m[1]], "kx", markersize=9, mew=2, label="peak")
    ax2.set_xlabel("u [m]")
    ax2.set_ylabel("v [m]")
    ax2.set_title(f"peak {fm.peak_wm2 / 1000:.2f} kW/m², power {fm.power_w / 1000:.2f} kW")
    ax2.legend(loc="lower right", fontsize=8)
    fig.colorbar(im, ax=ax2, label="kW/m²")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
