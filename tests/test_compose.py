"""docker-compose.yml and Dockerfile, checked without Docker (it does not run here).

The compose file is parsed with PyYAML and held against the code it drives: its commands
must be real ``vista`` subcommands, its ``VISTA_*`` variables real settings, and it must
run exactly one worker per job queue, all sharing the supervisor's artifact volume.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from supervisor.cli import app
from supervisor.settings import Settings

ROOT = Path(__file__).resolve().parent.parent
COMPOSE_FILE = ROOT / "docker-compose.yml"
DOCKERFILE = ROOT / "Dockerfile"
TORCH_PIN = "torch==2.13.0"
LONG_RUNNING = ("postgres", "redis", "supervisor")


def _load_compose() -> dict[str, Any]:
    with COMPOSE_FILE.open(encoding="utf-8") as handle:
        return yaml.safe_load(handle)


COMPOSE = _load_compose()
SERVICES: dict[str, dict[str, Any]] = COMPOSE["services"]


def _is_vista(service: dict[str, Any]) -> bool:
    """Built from this repository's Dockerfile (entrypoint ``vista``)."""
    return "build" in service or str(service.get("image", "")).startswith("vista")


VISTA_SERVICES = sorted(name for name, service in SERVICES.items() if _is_vista(service))


def _args(name: str) -> list[str]:
    """The service's command as arguments of ``vista`` (the image's entrypoint)."""
    command = SERVICES[name].get("command")
    assert command, f"service {name!r} has no command; it would run the image default"
    args = shlex.split(command) if isinstance(command, str) else [str(a) for a in command]
    if args and args[0] == "vista":
        args = args[1:]
    return args


def _environment(name: str) -> dict[str, str]:
    env = SERVICES[name].get("environment") or {}
    if isinstance(env, list):
        env = dict(item.split("=", 1) for item in env)
    return {key: value for key, value in env.items()}


def _worker_queues(name: str) -> list[str]:
    args = _args(name)
    for i, arg in enumerate(args):
        if arg == "--queues" and i + 1 < len(args):
            return [q.strip() for q in args[i + 1].split(",") if q.strip()]
        if arg.startswith("--queues="):
            return [q.strip() for q in arg.split("=", 1)[1].split(",") if q.strip()]
    return []


WORKERS = sorted(name for name in VISTA_SERVICES if _args(name)[:1] == ["worker"])


def _registry_queues(extra_env: dict[str, str]) -> list[str]:
    """``load_kinds(); queues()`` as ``vista worker`` sees them, in a fresh interpreter:
    this process's registry also holds the kinds other tests load (``tests.jobkinds``)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("VISTA_")}
    env.update(extra_env)
    script = (
        "import json\n"
        "from supervisor.engine.registry import load_kinds, queues\n"
        "from supervisor.settings import Settings\n"
        "load_kinds(Settings().extra_job_kinds)\n"
        "print(json.dumps(queues()))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, f"listing the job queues failed:\n{done.stderr}"
    return json.loads(done.stdout.strip().splitlines()[-1])


def _dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) pairs, continuation lines joined, comments dropped."""
    text = DOCKERFILE.read_text(encoding="utf-8")
    lines = [line for line in text.splitlines() if not line.lstrip().startswith("#")]
    joined = re.sub(r"\\\n", " ", "\n".join(lines))
    pairs = []
    for line in joined.splitlines():
        if line.strip():
            instruction, _, rest = line.strip().partition(" ")
            pairs.append((instruction.upper(), rest.strip()))
    return pairs


def test_vista_services_found() -> None:
    assert {"migrate", "supervisor"} <= set(VISTA_SERVICES), (
        f"expected the vista services migrate and supervisor, found {VISTA_SERVICES}"
    )
    assert WORKERS, "no `vista worker` service in docker-compose.yml"


@pytest.mark.parametrize("name", VISTA_SERVICES)
def test_command_is_a_vista_subcommand(name: str) -> None:
    args = _args(name)
    result = CliRunner().invoke(app, [*args, "--help"])
    assert result.exit_code == 0, (
        f"service {name!r} runs `vista {' '.join(args)}`, which the vista CLI rejects "
        f"(exit {result.exit_code}):\n{result.output}"
    )


def test_cli_help_check_rejects_unknown_commands() -> None:
    """The check above means something: a made-up subcommand or option fails it."""
    runner = CliRunner()
    assert runner.invoke(app, ["no-such-command", "--help"]).exit_code != 0
    assert runner.invoke(app, ["worker", "--no-such-option", "x", "--help"]).exit_code != 0


def test_expected_commands() -> None:
    assert _args("migrate") == ["migrate"], "the migrate service must run `vista migrate`"
    assert _args("supervisor")[:1] == ["serve"], "the supervisor service must run `vista serve`"


def test_vista_variables_are_settings_fields() -> None:
    fields = set(Settings.model_fields)
    seen: dict[str, str] = {}
    for name in SERVICES:
        for key in _environment(name):
            if key.startswith("VISTA_"):
                seen.setdefault(key, f"service {name!r}")
    for instruction, rest in _dockerfile_instructions():
        if instruction == "ENV":
            for key in re.findall(r"\b(VISTA_[A-Z0-9_]+)=", rest):
                seen.setdefault(key, "the Dockerfile")
    assert seen, "no VISTA_* variables found in docker-compose.yml"
    unknown = {
        key: where
        for key, where in seen.items()
        if key.removeprefix("VISTA_").lower() not in fields
    }
    assert not unknown, (
        f"VISTA_* variables that supervisor.settings.Settings does not read (silently "
        f"ignored): {unknown}; the fields are {sorted(fields)}"
    )


def test_vista_services_share_the_anchored_environment() -> None:
    shared = COMPOSE.get("x-vista-env")
    assert isinstance(shared, dict), "docker-compose.yml needs the x-vista-env anchor"
    for name in VISTA_SERVICES:
        assert _environment(name) == shared, (
            f"service {name!r} does not use the shared environment (<<: *vista-env)"
        )
    for key, value in shared.items():
        assert isinstance(value, str), (
            f"x-vista-env {key} = {value!r} should be a quoted string, not {type(value).__name__}"
        )


def test_settings_accept_compose_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    env = COMPOSE["x-vista-env"]
    for key in list(os.environ):
        if key.startswith("VISTA_"):
            monkeypatch.delenv(key)
    for key, value in env.items():
        monkeypatch.setenv(key, str(value))
    settings = Settings()
    assert settings.resolved_database_url == env["VISTA_DATABASE_URL"]
    assert settings.resolved_database_url.startswith("postgresql+psycopg://"), (
        "the compose database must be PostgreSQL through psycopg 3"
    )
    assert settings.broker_url == env["VISTA_BROKER_URL"]
    assert settings.resolved_artifact_dir == Path(env["VISTA_ARTIFACT_DIR"])
    assert settings.data_dir == Path(env["VISTA_DATA_DIR"])
    assert settings.host == "0.0.0.0", "the supervisor must listen on all interfaces"
    assert settings.port == int(env["VISTA_PORT"])


def test_one_worker_per_queue() -> None:
    env = {k: str(v) for k, v in COMPOSE["x-vista-env"].items()}
    queues = _registry_queues(env)
    assert queues, "the job registry lists no queues"
    by_worker = {name: _worker_queues(name) for name in WORKERS}
    for name, named in by_worker.items():
        assert len(named) == 1, (
            f"worker {name!r} must name exactly one queue with --queues, got {named} "
            "(without --queues it would consume every queue)"
        )
        assert name == f"worker-{named[0]}", (
            f"worker {name!r} runs queue {named[0]!r}; name it 'worker-{named[0]}'"
        )
    served = sorted(q for named in by_worker.values() for q in named)
    missing = sorted(set(queues) - set(served))
    extra = sorted(set(served) - set(queues))
    duplicated = sorted({q for q in served if served.count(q) > 1})
    assert not missing, f"queues without a worker service: {missing} (add worker-<queue>)"
    assert not extra, f"worker services for queues the registry does not know: {extra}"
    assert not duplicated, f"queues with more than one worker service: {duplicated}"


def _mount_of(name: str, target: str) -> tuple[str, bool] | None:
    """(source, read_only) of the service's volume mounted at ``target``."""
    for volume in SERVICES[name].get("volumes") or []:
        if isinstance(volume, str):
            parts = volume.split(":")
            if len(parts) >= 2 and parts[1] == target:
                return parts[0], len(parts) > 2 and "ro" in parts[2].split(",")
        elif volume.get("target") == target:
            return str(volume.get("source")), bool(volume.get("read_only"))
    return None


def test_artifact_volume_shared_by_supervisor_and_workers() -> None:
    declared = set(COMPOSE.get("volumes") or {})
    sources = {}
    for name in ["supervisor", *WORKERS]:
        target = _environment(name).get("VISTA_ARTIFACT_DIR")
        assert target, f"service {name!r} does not set VISTA_ARTIFACT_DIR"
        mount = _mount_of(name, target)
        assert mount is not None, (
            f"service {name!r} mounts no volume at VISTA_ARTIFACT_DIR {target}"
        )
        source, read_only = mount
        assert source in declared, (
            f"service {name!r} mounts {source!r} at {target}; use a named volume declared "
            f"under top-level volumes ({sorted(declared)})"
        )
        assert not read_only, f"service {name!r} mounts the artifacts read-only"
        sources[name] = (source, target)
    assert len(set(sources.values())) == 1, (
        f"supervisor and workers must share one artifact volume at one path: {sources}"
    )


def test_service_wiring() -> None:
    for name in ("postgres", "redis", "supervisor"):
        assert SERVICES[name].get("healthcheck", {}).get("test"), f"{name!r} needs a healthcheck"
    assert str(SERVICES["postgres"]["image"]).startswith("postgres:16")
    assert str(SERVICES["redis"]["image"]).startswith("redis:7")
    supervisor = SERVICES["supervisor"]
    assert "/readyz" in " ".join(map(str, supervisor["healthcheck"]["test"])), (
        "the supervisor healthcheck must ask /readyz"
    )
    assert any(str(p).split(":")[-1] == "8000" for p in supervisor.get("ports", [])), (
        "the supervisor must publish port 8000"
    )
    expected = {
        "migrate": "service_completed_successfully",
        "postgres": "service_healthy",
        "redis": "service_healthy",
    }
    for name in ["supervisor", *WORKERS]:
        depends = SERVICES[name].get("depends_on") or {}
        conditions = {dep: (spec or {}).get("condition") for dep, spec in depends.items()}
        assert conditions == expected, f"service {name!r} depends_on {conditions}, not {expected}"
    for name in [*LONG_RUNNING, *WORKERS]:
        assert SERVICES[name].get("restart") == "unless-stopped", (
            f"long-running service {name!r} needs restart: unless-stopped"
        )
    assert SERVICES["migrate"].get("restart", "no") == "no", "migrate is one-shot"


def test_dockerfile() -> None:
    instructions = _dockerfile_instructions()
    by_name: dict[str, list[str]] = {}
    for instruction, rest in instructions:
        by_name.setdefault(instruction, []).append(rest)
    assert by_name["FROM"][0].startswith("python:3.11-slim-bookworm"), by_name["FROM"]
    assert json.loads(by_name["ENTRYPOINT"][-1]) == ["vista"], 'ENTRYPOINT must be ["vista"]'
    assert json.loads(by_name["CMD"][-1]) == ["serve"], 'default CMD must be ["serve"]'
    runs = by_name.get("RUN", [])
    assert any(re.search(rf"pip install\b.*\b{re.escape(TORCH_PIN)}(\s|$)", r) for r in runs), (
        f"the Dockerfile must pip install {TORCH_PIN}"
    )
    assert any(re.search(r"pip install\b.*-e \"?\.", r) for r in runs), "missing `pip install -e .`"
    user = (by_name.get("USER") or ["root"])[-1]
    assert user not in ("root", "0"), "the image must run as a non-root user"
    copied = set()
    for rest in by_name.get("COPY", []):
        for source in rest.split()[:-1]:
            if not source.startswith("--"):
                assert (ROOT / source).exists(), f"Dockerfile copies {source}, which is missing"
                copied.add(source)
    # every package of the product is in the image; the benches are not the product
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    packages = {p.rstrip("*") for p in project["tool"]["setuptools"]["packages"]["find"]["include"]}
    assert packages - {"benches"} <= copied, f"the image lacks {packages - {'benches'} - copied}"
    assert "benches" not in copied


def test_torch_pin_matches_pyproject() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    pins = [d for d in project["project"]["dependencies"] if re.match(r"torch\b", d)]
    assert pins == [TORCH_PIN], (
        f"pyproject pins {pins}; the Dockerfile installs {TORCH_PIN}; keep them equal"
    )
