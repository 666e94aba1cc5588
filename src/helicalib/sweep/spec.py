"""The sweep file and the runs it asks for, each with its own seed and directory.

A sweep file is YAML (``docs/sweep.md``)::

    field: ../../field_config/demo_north.yaml     # relative to the sweep file
    days: 0.25
    seeds: [1, 2]
    planners: [gaps, round-robin]
    scenarios: [../scenarios/windy.yaml]          # optional; default: the built-in default scenario
    starts: ["2026-06-01T06:00:00+06:18"]         # optional; default: the scenario's start, else 2026-06-01 local midnight
    heliostats: 4                                 # optional; N = the field's first N, or a list of ids
    fidelity: render                              # optional
    root_seed: 0                                  # optional
    keep_frames: false                            # optional
    spots_per_board: auto                         # optional; 1 (default), N or auto: beams taking turns

A *cell* is one (scenario, planner, start); a *run* is one cell with one seed ``k`` of ``seeds``.
The integer seed a run gives ``simulate_campaign`` (hidden errors, weather, soiling, noise) is
:func:`simulation_seed`: ``SeedSequence(entropy=root_seed, spawn_key=(cell_number, k))``'s first
32-bit word, where ``cell_number`` is the first 8 bytes (big-endian) of the SHA-256 of the cell
key. It depends on nothing but the root seed, the cell's key and ``k``: not on the order of the
lists, on other cells, or on which worker runs it when.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, ValidationError, field_validator

from helicalib.config import load_field_config, read_yaml, validation_error
from helicalib.errors import ConfigError
from helicalib.sim.scenario import Scenario, Time, load_scenario

DEFAULT_LABEL = "default"
"""Cell-key part of the built-in scenario and of the default start."""
PLANNERS = ("gaps", "round-robin", "round-robin-shared")
PROGRESS_EVERY = 1000
"""Runs laid out between two progress calls of :meth:`Sweep.runs`."""

Seed = Annotated[StrictInt, Field(ge=0)]
MAX_RUNS = 100_000
"""Runs one sweep may have (cells × seeds): each is a whole campaign with its own folder and database;
a larger grid is refused in one line (split it into several sweeps)."""


class SweepFile(BaseModel):
    """The sweep file's keys, as written (paths still relative to the file)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    field: str = Field(min_length=1)
    days: float = Field(gt=0, le=3660)
    seeds: list[Seed] = Field(min_length=1)
    planners: list[str] = Field(min_length=1)
    scenarios: list[str] | None = Field(default=None, min_length=1)
    starts: list[Time] | None = Field(default=None, min_length=1)
    fidelity: Literal["render", "fast"] = "render"
    heliostats: Any = None
    root_seed: StrictInt = Field(default=0, ge=0)
    keep_frames: StrictBool = False
    spots_per_board: Any = 1

    @field_validator("spots_per_board", mode="before")
    @classmethod
    def _spots(cls, value):
        if value == "auto" or (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            return value
        raise ValueError(f"expected a whole number ≥ 1 of visits on a board at once, or auto; got {value!r}")

    @field_validator("days", mode="before")
    @classmethod
    def _number(cls, value):
        if isinstance(value, (bool, str)):
            raise ValueError(f"expected a number of plant days, got {value!r}")
        return value

    @field_validator("seeds", "planners", "scenarios", "starts")
    @classmethod
    def _unique(cls, value):
        if value is not None:
            _once(value)
        return value

    @field_validator("planners")
    @classmethod
    def _planners(cls, value):
        for k, name in enumerate(value):
            if name not in PLANNERS:
                raise ValueError(f"[{k}] {name!r} is not a planner; choose from {', '.join(PLANNERS)}")
        return value

    @field_validator("heliostats")
    @classmethod
    def _heliostats(cls, value):
        if value is None:
            return value
        if isinstance(value, int) and not isinstance(value, bool):
            if value < 1:
                raise ValueError(f"expected a number of heliostats >= 1, got {value}")
            return value
        if isinstance(value, list) and value and all(isinstance(v, str) and v.strip() for v in value):
            _once(value)
            return value
        raise ValueError("expected a number N (the field's first N heliostats) or a non-empty list of heliostat ids")

    def run_count(self) -> int:
        """Runs of the grid: seeds × planners × scenarios × starts."""
        return len(self.seeds) * len(self.planners) * len(self.scenarios or [None]) * len(self.starts or [None])


def _once(items: list) -> None:
    """Refuse an item given twice, naming its place (one pass: a grid of 10^5 seeds is checked at once)."""
    first: dict = {}
    for k, item in enumerate(items):
        if first.setdefault(item, k) != k:
            raise ValueError(f"[{k}] {item!r} is given twice")


@dataclass(frozen=True)
class Run:
    """One simulation of a sweep: what to run, with which seed, where it writes."""

    cell: str
    scenario: str
    planner: str
    start: str
    start_s: float
    seed: int
    sim_seed: int
    days: float
    heliostat_ids: tuple[str, ...]
    fidelity: str
    keep_frames: bool
    run_dir: str
    digest: str
    spots_per_board: int | str = 1

    def as_dict(self) -> dict:
        out = asdict(self)
        out["heliostat_ids"] = list(self.heliostat_ids)
        return out


@dataclass(frozen=True)
class Sweep:
    """A checked sweep file with its field config and scenarios loaded."""

    source: Path
    spec: SweepFile
    cfg: Any
    scenarios: dict[str, Scenario]
    starts: dict[str, str | None]
    heliostat_ids: tuple[str, ...]

    def cells(self) -> list[tuple[str, str, str, str]]:
        """(cell key, scenario label, planner, start label) in file order."""
        return [(cell_key(s, p, t), s, p, t) for s in self.scenarios for p in self.spec.planners for t in self.starts]

    def runs(self, out_dir: str | Path, progress=None) -> list[Run]:
        """Every run of the grid, cell by cell, seeds in file order; ``out_dir`` is made absolute.
        ``progress(done, total)`` is called every :data:`PROGRESS_EVERY` runs (a large grid takes seconds)."""
        from helicalib.app.simulated import default_start_s
        from helicalib.geometry.sun import parse_time, to_unix_seconds

        out = Path(out_dir).resolve()
        field_digest = _sha(self.cfg.model_dump_json())
        total = self.spec.run_count()
        runs = []
        for key, scen, planner, start in self.cells():
            scenario = self.scenarios[scen]
            text = self.starts[start] or scenario.start
            start_s = float(to_unix_seconds([parse_time(text)])[0]) if text else default_start_s(self.cfg)
            scenario_digest = _sha(scenario.model_dump_json())
            cell_dir = str(run_dir(out, key, 0).parent)      # joined as text: Path arithmetic per run is slow
            for k in self.spec.seeds:
                sim_seed = simulation_seed(self.spec.root_seed, key, k)
                what = {"field": field_digest, "scenario": scenario_digest, "days": self.spec.days,
                        "heliostats": list(self.heliostat_ids), "planner": planner, "start_s": start_s,
                        "sim_seed": sim_seed, "fidelity": self.spec.fidelity}
                if self.spec.spots_per_board != 1:  # a sweep of one visit per board keeps its earlier digests
                    what["spots_per_board"] = self.spec.spots_per_board
                runs.append(Run(cell=key, scenario=scen, planner=planner, start=text or "", start_s=start_s, seed=k,
                                sim_seed=sim_seed, days=self.spec.days, heliostat_ids=self.heliostat_ids,
                                fidelity=self.spec.fidelity, keep_frames=self.spec.keep_frames,
                                run_dir=os.path.join(cell_dir, f"seed-{k}"), digest=_sha(json.dumps(what, sort_keys=True)),
                                spots_per_board=self.spec.spots_per_board))
                if progress is not None and len(runs) % PROGRESS_EVERY == 0:
                    progress(len(runs), total)
        return runs


def cell_key(scenario: str, planner: str, start: str) -> str:
    """``<scenario>__<planner>__<start>``: the cell's directory name and the source of its seeds."""
    return f"{scenario}__{planner}__{start}"


def run_dir(out_dir: Path, cell: str, seed: int) -> Path:
    """``OUT/cells/<cell key>/seed-<k>``: the run's database, observations and result."""
    return Path(out_dir) / "cells" / cell / f"seed-{seed}"


def cell_number(cell: str) -> int:
    """The first 8 bytes of the SHA-256 of the cell key, big-endian: the cell's place in the seed tree."""
    return int.from_bytes(hashlib.sha256(cell.encode("utf-8")).digest()[:8], "big")


def simulation_seed(root_seed: int, cell: str, seed: int) -> int:
    """The integer seed of one run: ``SeedSequence(entropy=root_seed, spawn_key=(cell_number(cell),
    seed)).generate_state(1, dtype=uint32)[0]`` (the same as spawning child ``cell_number`` of
    ``SeedSequence(root_seed)``, then its child ``seed``)."""
    seq = np.random.SeedSequence(entropy=int(root_seed), spawn_key=(cell_number(cell), int(seed)))
    return int(seq.generate_state(1, dtype=np.uint32)[0])


def fidelity_supported() -> bool:
    """Whether a simulated campaign takes a ``fidelity`` (else every run renders frames)."""
    from helicalib.app.simulated import SimulationOptions

    return "fidelity" in {f.name for f in dataclasses.fields(SimulationOptions)}


def load_sweep(path: str | Path) -> Sweep:
    """Read and check a sweep file; every problem is a :class:`ConfigError` naming the file and key."""
    path = Path(path)
    try:
        spec = SweepFile.model_validate(read_yaml(path))
    except ValidationError as exc:
        raise validation_error(exc, path) from None
    if spec.run_count() > MAX_RUNS:
        raise ConfigError(f"{path}: seeds: {len(spec.seeds)} seeds x {spec.run_count() // len(spec.seeds)} cells = "
                          f"{spec.run_count()} runs; a sweep has at most {MAX_RUNS} runs (split it into several "
                          "sweeps)")
    base = path.parent
    if spec.fidelity != "render" and not fidelity_supported():
        raise ConfigError(f"{path}: fidelity: {spec.fidelity!r} is not available yet (the simulated campaign "
                          "renders every camera frame); use fidelity: render")
    cfg = load_field_config(_existing(base / spec.field, path, "field"))
    scenarios: dict[str, Scenario] = {}
    for k, rel in enumerate(spec.scenarios or []):
        label = _label(Path(rel).stem)
        if label in scenarios:
            raise ConfigError(f"{path}: scenarios[{k}]: {rel!r}: another scenario has the name {label!r}; "
                              "the file names (without .yaml) name the cells, so rename one")
        scenarios[label] = load_scenario(_existing(base / rel, path, f"scenarios[{k}]"))
    if not scenarios:
        scenarios[DEFAULT_LABEL] = Scenario()
    starts: dict[str, str | None] = {}
    for k, text in enumerate(spec.starts or []):
        label = _label(text.replace(":", "").replace(" ", "T"))
        if label in starts:
            raise ConfigError(f"{path}: starts[{k}]: {text!r} names the same cell as {starts[label]!r}")
        starts[label] = text
    if not starts:
        starts[DEFAULT_LABEL] = None
    return Sweep(source=path, spec=spec, cfg=cfg, scenarios=scenarios, starts=starts,
                 heliostat_ids=_heliostats(cfg, spec.heliostats, path))


def _heliostats(cfg, choice, path: Path) -> tuple[str, ...]:
    ids = [h.id for h in cfg.heliostats]
    if choice is None:
        return tuple(ids)
    if isinstance(choice, int):
        if choice > len(ids):
            raise ConfigError(f"{path}: heliostats: {choice}: the field has only {len(ids)} heliostats")
        return tuple(ids[:choice])
    for k, hid in enumerate(choice):
        if hid not in ids:
            raise ConfigError(f"{path}: heliostats[{k}]: {hid!r} is not a heliostat of {cfg.source}")
    return tuple(choice)


def _existing(file: Path, sweep: Path, key: str) -> Path:
    if not file.is_file():
        raise ConfigError(f"{sweep}: {key}: {file}: file not found (paths are relative to the sweep file)")
    return file


def _label(text: str) -> str:
    """A name safe as a directory name: letters, digits and ``.+-_`` kept, anything else ``-``."""
    return re.sub(r"[^0-9A-Za-z.+_-]", "-", text) or "-"


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
