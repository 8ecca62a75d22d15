"""The layout's rules, checked on the source: the services and the job contract never
reach into the supervisor, and the contract into neither side; libraries import no
service; no module imports itself through others (no cycle, function-level imports too);
the job engine sits below the domains it serves (it reaches them through its port only)
and the benches live outside the product's packages."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


PACKAGES = ("contract", "services", "supervisor", "benches")
LIBRARIES = "services.lib"
"""Code any service may use (archives, processes, wording, networks, point clouds); it knows
no service."""


def imported_modules(folder: str) -> dict[str, set[str]]:
    """Every module each file under ``folder`` imports (absolute names)."""
    found = {}
    for path in sorted((ROOT / folder).rglob("*.py")):
        names = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module)
        found[str(path.relative_to(ROOT))] = names
    return found


def reaching(folder: str, forbidden: tuple[str, ...]) -> dict[str, list[str]]:
    return {
        path: sorted(n for n in names if n.split(".")[0] in forbidden)
        for path, names in imported_modules(folder).items()
        if any(n.split(".")[0] in forbidden for n in names)
    }


def test_services_import_nothing_from_the_supervisor():
    assert len(imported_modules("services")) > 40  # the walk sees the services
    assert reaching("services", ("supervisor", "tests")) == {}


def test_the_contract_imports_neither_side():
    assert reaching("contract", ("supervisor", "services", "tests")) == {}


def test_the_python_clients_word_lists_are_the_servers():
    """The SDK checks judgments before queuing them with its own copy of the lists (it
    does not depend on the server's package): the same words."""
    from vista_client import headset

    from contract.vocabulary import DEFECT_TYPES
    from supervisor.models.defects import VERDICTS

    assert headset.VERDICTS == VERDICTS and headset.DEFECT_TYPES == DEFECT_TYPES


def test_the_headsets_and_the_dashboards_finding_types_are_the_servers():
    """The Unity core and the dashboard list the finding types too (a reclassification to
    a type they lack would be refused on the headset, drawn without its colour on the
    page): the same words, in the server's order."""
    from contract.vocabulary import DEFECT_TYPES

    models = (ROOT / "clients/unity/Runtime/Core/Models.cs").read_text()
    unity = re.search(r"class DefectTypes.*?All = \{([^}]*)\}", models, re.S).group(1)
    assert tuple(re.findall(r'"(\w+)"', unity)) == DEFECT_TYPES
    web = (ROOT / "clients/web/src/main.js").read_text()
    listed = re.search(r"const TYPES = \[([^\]]*)\]", web).group(1)
    assert tuple(re.findall(r'"(\w+)"', listed)) == DEFECT_TYPES


def module_names() -> dict[str, Path]:
    """Every module of the packages by dotted name (a package by its own name)."""
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def import_graph() -> dict[str, set[str]]:
    """Module → the modules it imports (at any depth of the file, relative imports
    resolved; ``from a import b`` is an edge to ``a.b`` when that is a module)."""
    modules = module_names()

    def known(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                edges |= {known(alias.name) for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parents = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(parents + ([node.module] if node.module else []))
                for alias in node.names:
                    full = f"{base}.{alias.name}"
                    edges.add(full if full in modules else known(base))
        graph[name] = edges - {None, name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            child = next((e for e in edges if e in graph), None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    found.append(sorted(group))
    return found


def test_the_cycle_finder_finds_a_planted_cycle():
    planted = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e"}}
    assert cycles(planted) == [["a", "b", "c"]]


def test_no_module_imports_itself_through_others():
    graph = import_graph()
    assert len(graph) > 200 and "services.odometry.run" in graph["services.odometry.jobs"]
    assert cycles(graph) == []


def test_libraries_import_no_service():
    graph = import_graph()
    inside = [name for name in graph if _within(name, LIBRARIES)]
    assert len(inside) > 10
    reaching_services = {
        name: sorted(
            target
            for target in graph[name]
            if target.startswith("services.") and not _within(target, LIBRARIES)
        )
        for name in inside
    }
    assert {k: v for k, v in reaching_services.items() if v} == {}


def services_reaching_others(graph: dict[str, set[str]], uses: dict[str, tuple]) -> dict:
    """Service modules importing another service's code that their service does not name
    in its ``kinds.USES`` (a library is anyone's to use)."""
    found = {}
    for name, targets in graph.items():
        own = _service_of(name)
        if own is None:
            continue
        others = sorted(
            t
            for t in targets
            if _service_of(t) not in (None, own) and _service_of(t) not in uses.get(own, ())
        )
        if others:
            found[name] = others
    return found


def _service_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "services" or len(parts) < 2 or _within(module, LIBRARIES):
        return None
    return parts[1]


def _declared_uses() -> dict[str, tuple]:
    import importlib

    services = [p.name for p in (ROOT / "services").iterdir() if (p / "kinds.py").exists()]
    return {
        s: getattr(importlib.import_module(f"services.{s}.kinds"), "USES", ()) for s in services
    }


def test_a_service_reaches_another_only_when_it_names_it():
    graph, uses = import_graph(), _declared_uses()
    assert uses["defects"] == ("stitching",) and len(uses) >= 6
    assert "services.stitching.stitch" in graph["services.defects.example"]
    assert services_reaching_others(graph, uses) == {}
    undeclared = {**uses, "defects": ()}
    assert "services.defects.example" in services_reaching_others(graph, undeclared)


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def supervisor_reaching_into_services(graph: dict[str, set[str]]) -> dict[str, list[str]]:
    """Supervisor modules importing a service module: it knows a service only through the
    registry (``supervisor.engine.registry`` names the services' ``kinds`` modules as
    strings and loads the hooks they declare); the libraries are its to use."""
    return {
        name: sorted(t for t in targets if _within(t, "services") and not _within(t, LIBRARIES))
        for name, targets in graph.items()
        if _within(name, "supervisor")
        and any(_within(t, "services") and not _within(t, LIBRARIES) for t in targets)
    }


def test_the_supervisor_knows_services_only_through_the_registry():
    graph = import_graph()
    assert "services.lib.pointcloud.ply" in graph["supervisor.exports.scene"]  # a library
    assert supervisor_reaching_into_services(graph) == {}


def test_a_planted_service_import_in_the_supervisor_is_found():
    graph = import_graph()
    graph["supervisor.exports.scene"] = graph["supervisor.exports.scene"] | {
        "services.defects.kinds"
    }
    assert supervisor_reaching_into_services(graph) == {
        "supervisor.exports.scene": ["services.defects.kinds"]
    }


ENGINE = "supervisor.engine"
ENGINE_BELOW = ("supervisor.models", "supervisor.storage", "supervisor.db", "supervisor.settings")
ENGINE_BELOW += ("supervisor.changes",)
"""What the engine stands on besides itself: the schema, files, the database, settings and
the change log. A domain's service (artifacts, defects, jobs, inspections…) is reached
through ``supervisor.engine.port`` only."""
ENGINE_PUBLIC = ("registry", "runtime", "dispatch", "graph", "transient", "port")
"""The engine's modules a domain may import; the rest (runner, context, transitions,
maintenance, embedded, broker) are its own."""
COMPOSITION_ROOTS = ("supervisor.app", "supervisor.worker_app")
"""Where a process is assembled: the engine's parts and the domains' side of its port."""


def engine_reaching_up(graph: dict[str, set[str]]) -> dict[str, list[str]]:
    """Engine modules importing a supervisor module the engine does not stand on."""
    found = {}
    for name, targets in graph.items():
        if not _within(name, ENGINE):
            continue
        above = sorted(
            t
            for t in targets
            if _within(t, "supervisor")
            and t != "supervisor"
            and not _within(t, ENGINE)
            and not any(_within(t, below) for below in ENGINE_BELOW)
        )
        if above:
            found[name] = above
    return found


def domains_reaching_engine_internals(graph: dict[str, set[str]]) -> dict[str, list[str]]:
    """Modules outside the engine (its composition roots aside) importing an engine module
    that is not one of its public ones."""
    public = {f"{ENGINE}.{m}" for m in ENGINE_PUBLIC} | {ENGINE}
    return {
        name: sorted(t for t in targets if _within(t, ENGINE) and t not in public)
        for name, targets in graph.items()
        if not _within(name, ENGINE)
        and name not in COMPOSITION_ROOTS
        and any(_within(t, ENGINE) and t not in public for t in targets)
    }


def test_the_engine_imports_no_domain():
    graph = import_graph()
    assert "supervisor.engine.port" in graph["supervisor.engine.runner"]
    assert engine_reaching_up(graph) == {}
    planted = {**graph, "supervisor.engine.runner": {"supervisor.defects.service"}}
    assert engine_reaching_up(planted) == {
        "supervisor.engine.runner": ["supervisor.defects.service"]
    }


def test_domains_use_only_the_engines_public_modules():
    graph = import_graph()
    assert "supervisor.engine.embedded" in graph["supervisor.app"]  # a composition root
    assert domains_reaching_engine_internals(graph) == {}
    planted = {**graph, "supervisor.jobs.service": {"supervisor.engine.runner"}}
    assert domains_reaching_engine_internals(planted) == {
        "supervisor.jobs.service": ["supervisor.engine.runner"]
    }


def test_the_benches_live_outside_the_product():
    """Load generators, an HTTP client and a browser launcher are not the product: the
    supervisor's package holds none, and the product imports the benches only inside
    the commands that run them (``vista api bench``, ``vista clients bench``)."""
    assert not (ROOT / "supervisor" / "bench").exists()
    graph = import_graph()
    assert "benches.seeding" in graph["benches.api"]
    product = ("contract", "services", "supervisor")
    reaching = {
        name: sorted(t for t in targets if _within(t, "benches"))
        for name, targets in graph.items()
        if name.split(".")[0] in product and any(_within(t, "benches") for t in targets)
    }
    assert reaching == {"supervisor.cli": ["benches.api", "benches.clients"]}
    top_level = {
        node.module
        for node in ast.parse((ROOT / "supervisor" / "cli.py").read_text()).body
        if isinstance(node, ast.ImportFrom) and node.module
    }
    assert not any(_within(m, "benches") for m in top_level)
