"""The layout's rules, checked on the source: the services and the job contract never
reach into the supervisor, and the contract into neither side."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


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

    from supervisor.models.defects import DEFECT_TYPES, VERDICTS

    assert headset.VERDICTS == VERDICTS and headset.DEFECT_TYPES == DEFECT_TYPES
