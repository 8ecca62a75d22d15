"""README's "First steps" run as pasted, against a fresh server: a user, a simulated scan,
an inspection, an upload, a run with live progress and the defects it found."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

from tests.conftest import make_settings

README = Path(__file__).resolve().parent.parent / "README.md"
VISTA = Path(sys.executable).parent / "vista"


def first_steps() -> str:
    text = README.read_text()
    section = text[text.index("## First steps") :]
    return re.search(r"```\n(.*?)```", section, re.S).group(1)


def test_first_steps_work_as_pasted(start_server, tmp_path, sqlite_url):
    settings = make_settings(tmp_path, sqlite_url, embedded_workers=1, extra_job_kinds=[])
    server = start_server(settings, run_engine=True)
    lines = first_steps().splitlines()
    assert lines[0].startswith("make run &")  # the server: started above instead
    script = "\n".join(lines[1:])
    script = script.replace("localhost:8000", server.url.removeprefix("http://"))
    script = script.replace(".venv/bin/vista", str(VISTA))
    env = {
        **os.environ,
        "VISTA_DATA_DIR": str(settings.data_dir),
        "VISTA_DATABASE_URL": settings.resolved_database_url,
    }
    done = subprocess.run(
        ["bash", "-euo", "pipefail", "-c", script],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    out = done.stdout
    assert '"username":"ada"' in out.replace(" ", "")
    assert 'event: end\ndata: {"status": "succeeded"}' in out, out[-2000:]
    defects = json.loads(out.strip().splitlines()[-1])
    assert len(defects["items"]) == 5 and all(
        d["job_id"] == defects["items"][0]["job_id"] for d in defects["items"]
    )


def test_the_tolerance_document_shown_is_the_defaults():
    """The README's tolerance document, its comments dropped, is a valid document giving
    every default limit."""
    from contract.tolerances import Limits, Tolerances, limits_of

    text = README.read_text(encoding="utf-8")
    block = text.split("The tolerance document", 1)[1].split("```", 2)[1]
    document = json.loads(re.sub(r"#[^\n]*", "", block))
    assert limits_of(Tolerances.model_validate(document)) == Limits()
    assert Tolerances.model_validate(document).model_dump(exclude_none=True) == document
