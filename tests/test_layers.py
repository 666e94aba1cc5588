"""The package's layers, read from the source (every import statement, top level or inside a function).

* the pure core (geometry, vision, calibration and the campaign's policy) knows no devices, store,
  simulator, console, commands or app;
* the campaign cannot tell a simulated plant from a real one and draws on no terminal, parses no
  arguments and runs no scheduler (those are the app's);
* devices know nothing of vision, flux, the campaign or the simulator;
* the report, the store and flux know nothing of the simulator, console, commands or app;
* the web console knows nothing of the app that attaches it;
* no two modules of helicalib import each other, directly or round a longer circle;
* the campaign never sniffs a plant's abilities with ``hasattr``/``getattr`` (a plant declares them,
  ``devices.protocols.abilities_of``).

docs/architecture.md describes these layers.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "helicalib"

PURE_PACKAGES = ("geometry", "vision", "calibration")
"""Packages of the pure core: arrays in, arrays or frozen dataclasses out."""
CAMPAIGN_POLICY = ("campaign/planner.py", "campaign/gating.py", "campaign/book.py", "campaign/verdict.py",
                   "campaign/choice.py", "campaign/operation/rules.py")
"""The campaign's pure policy modules."""
PURE_FORBIDDEN = ("helicalib.devices", "helicalib.store", "helicalib.sim", "helicalib.console", "helicalib.commands",
                  "helicalib.app")
CAMPAIGN_FORBIDDEN = ("helicalib.sim", "helicalib.console", "helicalib.app", "helicalib.commands", "argparse", "rich",
                      "apscheduler")
DEVICES_FORBIDDEN = ("helicalib.vision", "helicalib.flux", "helicalib.campaign", "helicalib.sim")
LIBRARY_PACKAGES = ("report", "store", "flux")
"""Packages below the edge that are not the pure core: they read and write files, and know no edge."""
LIBRARY_FORBIDDEN = ("helicalib.sim", "helicalib.console", "helicalib.app", "helicalib.commands")
CONSOLE_FORBIDDEN = ("helicalib.app",)
"""The web console is attached by the app (:mod:`helicalib.app.session`) and reaches no higher."""


def _module_name(path: Path, root: Path, package: str) -> str:
    """``root/a/b.py`` → ``package.a.b``; ``root/a/__init__.py`` → ``package.a``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([package, *parts])


def _statements(path: Path, root: Path = SRC, package: str = "helicalib") -> list[tuple[str, list[str] | None]]:
    """Every import statement of ``path`` as ``(module, names)``: ``import m`` → ``(m, None)``,
    ``from m import a, b`` → ``(m, [a, b])``; relative imports resolved against the file's package."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = _module_name(path, root, package).split(".") if path.is_relative_to(root) else [package]
    if path.name != "__init__.py":
        here = here[:-1]  # the package the module lives in
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((a.name, None) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join([*here[:len(here) - node.level + 1], *([base] if base else [])])
            if base:
                out.append((base, [a.name for a in node.names]))
    return out


def _imports(path: Path, root: Path = SRC, package: str = "helicalib") -> set[str]:
    """Every name ``path`` imports, absolute: the module and, for ``from m import a``, also ``m.a``."""
    out = set()
    for base, names in _statements(path, root, package):
        out.add(base)
        out.update(f"{base}.{a}" for a in names or ())
    return out


def _hits(names: set[str], forbidden: tuple[str, ...]) -> list[str]:
    return sorted(m for m in names if any(m == f or m.startswith(f + ".") for f in forbidden))


def _files(package: str) -> list[Path]:
    return sorted((SRC / package).rglob("*.py"))


# ---------------------------------------------------------------------------- layers
def _violations(files: list[Path], forbidden: tuple[str, ...]) -> dict[str, list[str]]:
    """Each file that imports something of ``forbidden``, with what (none: the layer holds)."""
    assert files
    bad = {str(f.relative_to(SRC)): _hits(_imports(f), forbidden) for f in files}
    return {k: v for k, v in bad.items() if v}


@pytest.mark.parametrize("package, forbidden", [("campaign", "helicalib.sim"), ("devices", "helicalib.flux"),
                                                ("devices", "helicalib.sim"), ("devices", "helicalib.campaign")])
def test_a_layer_imports_nothing_of_the_one_it_must_not_know(package, forbidden):
    files = sorted((SRC / package).glob("*.py"))
    assert files
    bad = {f.name: sorted(m for m in _imports(f) if m == forbidden or m.startswith(forbidden + "."))
           for f in files}
    assert not {k: v for k, v in bad.items() if v}, bad


def _pure_core_files() -> list[Path]:
    files = [f for p in PURE_PACKAGES for f in _files(p)]
    missing = [name for name in CAMPAIGN_POLICY if not (SRC / name).is_file()]
    assert not missing, f"pure policy modules named here but not in the package: {missing}"
    return files + [SRC / name for name in CAMPAIGN_POLICY]


def test_the_pure_core_imports_no_devices_store_sim_console_commands_or_app():
    files = _pure_core_files()
    assert len(files) > 20
    bad = _violations(files, PURE_FORBIDDEN)
    assert not bad, bad


PURE_MAY_IMPORT = ("helicalib.geometry", "helicalib.vision", "helicalib.calibration", "helicalib.config",
                   "helicalib.errors")
"""What of helicalib the pure core may import, besides the campaign's policy modules themselves."""


def test_the_pure_core_imports_only_the_pure_core_the_config_and_the_errors():
    """An allow-list: the pure core reaches no report, flux, realdata, sweep, nor any campaign module
    that is not policy (the loop, its state, the visit), whatever new package appears."""
    policy = {_module_name(SRC / name, SRC, "helicalib") for name in CAMPAIGN_POLICY}
    packages = {"helicalib", "helicalib.campaign", "helicalib.campaign.operation"}  # bases of `from p import m`
    allowed = PURE_MAY_IMPORT + tuple(policy)
    bad = {}
    for f in _pure_core_files():
        names = {m for m in _imports(f) if m == "helicalib" or m.startswith("helicalib.")}
        hits = sorted(m for m in names if m not in packages and not any(m == a or m.startswith(a + ".") for a in allowed))
        if hits:
            bad[str(f.relative_to(SRC))] = hits
    assert not bad, bad


def test_the_allow_list_check_sees_a_pure_module_reaching_the_loop(tmp_path):
    pkg = tmp_path / "helicalib" / "campaign"
    pkg.mkdir(parents=True)
    f = pkg / "book.py"
    f.write_text("from . import loop\nfrom ..report import html\n")
    names = _imports(f, tmp_path / "helicalib", "helicalib")
    assert {"helicalib.campaign.loop", "helicalib.report.html"} <= names


def test_the_campaign_imports_no_sim_console_app_commands_argparse_rich_or_apscheduler():
    bad = _violations(_files("campaign"), CAMPAIGN_FORBIDDEN)
    assert not bad, bad


def test_devices_import_no_vision_flux_campaign_or_sim():
    bad = _violations(_files("devices"), DEVICES_FORBIDDEN)
    assert not bad, bad


@pytest.mark.parametrize("package", LIBRARY_PACKAGES)
def test_report_store_and_flux_import_no_sim_console_app_or_commands(package):
    bad = _violations(_files(package), LIBRARY_FORBIDDEN)
    assert not bad, bad


def test_the_web_console_imports_nothing_of_the_app():
    bad = _violations(_files("console"), CONSOLE_FORBIDDEN)
    assert not bad, bad


def test_the_check_sees_an_import_inside_a_function(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from helicalib.sim.plant import SimulatedPlant\n    return SimulatedPlant\n")
    assert "helicalib.sim.plant" in _imports(f)


# ---------------------------------------------------------------------------- circles
def import_graph(root: Path, package: str) -> dict[str, set[str]]:
    """Module → the modules of ``package`` it imports. ``from p.x import y`` counts as an import of
    ``p.x.y`` when that is a module, else of ``p.x``; a name that is no module counts as the longest
    module its dotted name starts with."""
    modules = {_module_name(f, root, package): f for f in sorted(root.rglob("*.py"))}

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for mod, f in modules.items():
        targets = set()
        for base, names in _statements(f, root, package):
            if base != package and not base.startswith(package + "."):
                continue
            for name in names or (None,):
                sub = f"{base}.{name}"
                targets.add(sub if name is not None and sub in modules else resolve(base))
        graph[mod] = {t for t in targets if t and t != mod}
    return graph


def import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in graph:
                    continue
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        component.append(m)
                        if m == node:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
    return sorted(out)


def test_no_two_modules_import_each_other_round_a_circle():
    graph = import_graph(SRC, "helicalib")
    assert len(graph) > 100 and graph["helicalib.vision.spot"]
    circles = import_circles(graph)
    assert not circles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in circles)


def test_the_circle_finder_finds_a_planted_circle(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from pkg.sub.c import C\n")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from pkg.sub.c import C\n    return C\n")
    (pkg / "sub" / "c.py").write_text("import pkg.a\nC = 1\n")
    (pkg / "d.py").write_text("from pkg.a import x\nfrom pkg import sub\n")
    graph = import_graph(pkg, "pkg")
    assert graph["pkg.a"] == {"pkg.sub.b"} and graph["pkg.d"] == {"pkg.a", "pkg.sub"}
    assert import_circles(graph) == [["pkg.a", "pkg.sub.b", "pkg.sub.c"]]
    (pkg / "sub" / "c.py").write_text("C = 1\n")
    assert import_circles(import_graph(pkg, "pkg")) == []


# ---------------------------------------------------------------------------- abilities
def _sniffs(path: Path) -> list[str]:
    """``hasattr(...)``/``getattr(...)`` calls whose first argument's source mentions a plant."""
    text = path.read_text(encoding="utf-8")
    out = []
    for node in ast.walk(ast.parse(text, filename=str(path))):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("hasattr", "getattr")
                and node.args and "plant" in (ast.get_source_segment(text, node.args[0]) or "").lower()):
            out.append(f"line {node.lineno}: {ast.get_source_segment(text, node)}")
    return out


def test_the_campaign_never_sniffs_a_plants_abilities():
    bad = {str(f.relative_to(SRC)): _sniffs(f) for f in _files("campaign")}
    assert not {k: v for k, v in bad.items() if v}, bad


def test_the_sniff_check_sees_getattr_on_a_plant(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f(self, err):\n    many = getattr(self.plant, 'track_many', None)\n"
                 "    return hasattr(err, 'reason'), many\n")
    assert _sniffs(f) == ["line 2: getattr(self.plant, 'track_many', None)"]
