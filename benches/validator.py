"""The Khronos glTF validator (npm package gltf-validator, clients/web) on one file."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

WEB = Path(__file__).resolve().parent.parent.parent / "clients" / "web"


def validate_gltf(path: Path) -> dict:
    """The Khronos validator's counts for one glTF file."""
    done = subprocess.run(
        ["node", str(WEB / "tools" / "validate-gltf.mjs"), str(path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if done.returncode not in (0, 1):
        raise RuntimeError(f"the glTF validator failed: {done.stderr}")
    issues = json.loads(done.stdout)[0]["issues"]
    return {k: issues[k] for k in ("numErrors", "numWarnings", "numInfos", "numHints")}
