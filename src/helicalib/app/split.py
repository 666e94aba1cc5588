"""One simulated campaign split over the cores and machines of a Dask cluster.

:func:`plan_groups` cuts the field into groups of boards with the heliostats they serve (each
heliostat's ``target``): the boards in the config's order, cut where the heliostat count reaches
its share, so neighbouring boards stay together. A board is never lent across groups (a group's
campaign sees only its own boards' cameras). :func:`run_group` is one group's campaign, a plain
function of picklable arguments that a remote worker runs: the SAME simulated plant (the whole
field's, built from the field file, so every heliostat keeps its row and its row's seeds: its
hidden truth, jitter, soiling and drift are those of the unsplit run), the same weather, start
and clock, with the campaign restricted to the group's heliostats and boards, into its own folder.
:func:`simulate_split` submits the groups, reports each as it ends, merges the finished ones into
one campaign of one database (:mod:`helicalib.store.merge`) and one summary
(:mod:`.split_summary`); a group that failed is named with its reason in the summary and the
campaign's settings, and its heliostats stay in the campaign, unvisited.
"""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field, replace
from pathlib import Path

from helicalib.app.cluster import TaskFailed, call_reporting, failure_of
from helicalib.app.simulated import SimulationOptions, default_start_s
from helicalib.app.split_summary import combine_summaries
from helicalib.errors import ConfigError

GROUPS_DIR = "groups"
"""The work folder under the output folder: one sub-folder per group (``g1``, ``g2`` ...)."""
GROUP_OUTPUT = "simulate group"
"""The marker's word for a group's folder (:mod:`helicalib.outdir`): only such a folder is cleared."""


@dataclass(frozen=True)
class Group:
    """One group of boards (``index`` from 1) and the campaign's heliostats they serve."""

    index: int
    boards: tuple[str, ...]
    heliostats: tuple[str, ...]

    @property
    def name(self) -> str:
        return f"g{self.index}"


@dataclass
class SplitResult:
    """The merged summary and database, and the groups that failed (group → one-line reason)."""

    summary: dict
    database: Path
    failures: dict[int, str] = field(default_factory=dict)


class GroupFailed(TaskFailed):
    """A group's campaign raised (:class:`~helicalib.app.cluster.TaskFailed`)."""


def plan_groups(cfg, n_groups: int, heliostat_ids: list[str] | None = None) -> list[Group]:
    """At most ``n_groups`` groups of whole boards (module docstring); boards that serve none of the
    campaign's heliostats are left out. Raises :class:`ConfigError` for fewer than one group."""
    if n_groups < 1:
        raise ConfigError(f"--groups {n_groups}: must be at least 1")
    chosen = set(heliostat_ids) if heliostat_ids else None
    served = {t.id: [] for t in cfg.targets}
    for h in cfg.heliostats:
        if chosen is None or h.id in chosen:
            served[h.target].append(h.id)
    boards = [t.id for t in cfg.targets if served[t.id]]
    k = min(n_groups, len(boards))
    share = sum(len(served[b]) for b in boards) / max(k, 1)
    groups: list[list[str]] = [[]]
    done = 0
    for i, b in enumerate(boards):
        left_boards, left_groups = len(boards) - i, k - len(groups)
        if groups[-1] and left_groups > 0 and (left_boards <= left_groups
                                               or done + len(served[b]) / 2 > share * len(groups)):
            groups.append([])
        groups[-1].append(b)
        done += len(served[b])
    return [Group(i + 1, tuple(bs), tuple(h for b in bs for h in served[b])) for i, bs in enumerate(groups) if bs]


def run_group(field_path: str, group: Group, options: SimulationOptions, out_dir: str) -> dict:
    """One group's campaign into ``out_dir`` (cleared when it is an earlier group's folder); returns
    its summary. Any exception comes out as :class:`GroupFailed`."""
    return call_reporting(_run_group, field_path, group, options, out_dir, failure=GroupFailed)


def _run_group(field_path: str, group: Group, options: SimulationOptions, out_dir: str) -> dict:
    from helicalib.app.simulated import simulate_campaign
    from helicalib.config import load_field_config
    from helicalib.outdir import prepare

    cfg = load_field_config(field_path)
    out = prepare(out_dir, GROUP_OUTPUT, replace=True, option="group folder",
                  advice="remove it or give simulate another --out")
    opts = replace(options, heliostat_ids=list(group.heliostats), boards=tuple(group.boards))
    with open(out / "group.log", "w", encoding="utf-8") as log, redirect_stdout(log), redirect_stderr(log):
        result = simulate_campaign(cfg, out, opts)
    (out / "summary.json").write_text(json.dumps(result.summary, indent=2), encoding="utf-8")
    return result.summary


def simulate_split(cfg, field_path: str, out: Path, options: SimulationOptions, client, n_groups: int,
                   on_start: Callable[[list[Group]], None] | None = None,
                   on_group: Callable[[Group, str | None], None] | None = None,
                   task: Callable = run_group) -> SplitResult:
    """Run ``options``' campaign split into at most ``n_groups`` groups on ``client``'s cluster, merge
    it into ``out/helicalib.db`` and return the merged summary. ``on_start(groups)`` once they are
    planned; ``on_group(group, reason)`` as each ends (``reason`` None when it finished).
    ``task``: the function each group runs (:func:`run_group`; tests inject a failing one)."""
    from dask.distributed import as_completed

    wall0 = time.perf_counter()
    start_s = options.start_s if options.start_s is not None else default_start_s(cfg)
    options = replace(options, start_s=start_s)  # one clock: every group starts at the same instant
    groups = plan_groups(cfg, n_groups, options.heliostat_ids)
    if on_start is not None:
        on_start(groups)
    work = Path(out) / GROUPS_DIR
    tag = uuid.uuid4().hex[:8]
    futures = {client.submit(task, str(Path(field_path).resolve()), g, options, str((work / g.name).resolve()),
                             pure=False, retries=0, key=f"helicalib-simulate-{tag}-{g.name}"): g for g in groups}
    summaries: dict[int, dict] = {}
    failures: dict[int, tuple[str, str]] = {}
    try:
        for future in as_completed(futures):
            g = futures[future]
            reason = None
            if future.status == "finished":
                summaries[g.index] = future.result()
            else:
                what, tb = failure_of(future)
                reason = f"group {g.index} (boards {', '.join(g.boards)}): {what}"
                failures[g.index] = (reason, tb)
            if on_group is not None:
                on_group(g, reason)
    finally:
        client.cancel(list(futures))
    db = _merge(cfg, out, options, groups, summaries, failures)
    summary = combine_summaries([summaries[g.index] for g in groups if g.index in summaries])
    if "commissioned_day" in summary:
        summary.update(_merged_figures(db, sum(len(g.heliostats) for g in groups), start_s))
    summary["heliostats"] = sum(len(g.heliostats) for g in groups)
    summary["acceptance_rate"] = round(summary.get("accepted", 0) / max(summary["heliostats"], 1), 4)
    summary["split"] = _split_record(groups, summaries, failures)
    summary["wall_s"] = round(time.perf_counter() - wall0, 1)
    summary["fidelity"] = options.fidelity
    summary["database"] = str(db)
    if failures:  # the workers' tracebacks, beside the merged database
        (Path(out) / "failed_groups.log").write_text("".join(f"{r}\n{tb}\n" for r, tb in failures.values()),
                                                     encoding="utf-8")
    return SplitResult(summary, db, {k: v[0] for k, v in failures.items()})


def _split_record(groups: list[Group], summaries: dict, failures: dict) -> dict:
    return {"groups": len(groups),
            "boards": [list(g.boards) for g in groups],
            "heliostats": [len(g.heliostats) for g in groups],
            "group_wall_s": [summaries.get(g.index, {}).get("wall_s") for g in groups],
            "failed": [{"group": k, "reason": failures[k][0]} for k in sorted(failures)],
            "missing_heliostats": sum(len(g.heliostats) for g in groups if g.index in failures)}


def _merge(cfg, out: Path, options: SimulationOptions, groups: list[Group], summaries: dict,
           failures: dict) -> Path:
    """The finished groups merged into ``out/helicalib.db``; its observations into ``observations.csv``."""
    from helicalib.store.merge import merge_campaigns
    from helicalib.store.sqlite import Store

    work = Path(out) / GROUPS_DIR
    done = [g for g in groups if g.index in summaries]
    sources = [work / g.name / "helicalib.db" for g in done]
    settings: dict = {}
    if sources:
        with Store.open(sources[0], readonly=True) as first:
            settings = dict(first.campaigns()[-1].settings)
    settings.pop("images_dir", None)  # the merged database's own, recorded by the store
    settings["split"] = _split_record(groups, summaries, failures)
    planned = sorted(((h, cfg.heliostat_index(h), cfg.heliostat(h).target) for g in groups for h in g.heliostats),
                     key=lambda row: row[1])
    db = Path(out) / "helicalib.db"
    ended = options.start_s + options.days * 86400.0
    result = merge_campaigns(sources, db, name=f"simulate {cfg.site.name}", mode="simulate",
                             started_s=options.start_s, ended_s=ended, heliostats=planned,
                             status="stopped" if failures else "finished", config_path=str(cfg.source or ""),
                             settings=settings, owner=f"simulate {cfg.source or ''} (merging {len(done)} groups)")
    with Store.open(db, "images", durable=False) as store:
        store.export_observations_csv(Path(out) / "observations.csv", campaign_id=result.campaign_id)
    return db


def _merged_figures(db: Path, n_heliostats: int, start_s: float) -> dict:
    """The figures read again from the merged database: ``commissioned_day`` (95 % accepted at once)."""
    from helicalib.app.sim_figures import commissioning_time
    from helicalib.store.sqlite import Store

    with Store.open(db, readonly=True) as store:
        cid = store.campaigns()[-1].id
        t = commissioning_time(store, cid, n_heliostats)
    return {"commissioned_day": None if t is None else round((t - start_s) / 86400.0, 3)}
