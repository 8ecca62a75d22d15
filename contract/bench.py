"""What every `vista bench` shares: progress on stderr, the JSON document, the verdict."""

from __future__ import annotations

import json
import os
import platform
import sys
from datetime import UTC, datetime
from pathlib import Path


def say(message: str) -> None:
    """Progress for the person waiting (stderr, so the tables on stdout stay clean)."""
    print(message, file=sys.stderr, flush=True)


def write_document(out: Path, *, bench: str, targets: dict, **parts: object) -> dict:
    """Write bench-results JSON: which bench, when, on what machine, its targets, its parts."""
    document = {
        "bench": bench,
        "when": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        },
        "targets": targets,
        **parts,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(document, indent=1) + "\n")
    return document


def print_verdict(verdict: dict[str, bool], out: Path) -> None:
    print("\n## Targets\n")
    for name, met in verdict.items():
        print(f"- {name}: {'met' if met else 'NOT met'}")
    print(f"\nwrote {out}")
