"""The ``vista`` command."""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import typer

from contract.cli import alias, fail, unwrap_help
from contract.tolerances import Tolerances, finding_line, limits_of
from services.lib.wording import counted
from supervisor.engine.registry import declared_hooks
from supervisor.settings import get_settings, secure_data_dir
from supervisor.users import cli as users_cli

app = typer.Typer(
    help="vista: 3D inspection and perception — supervisor, job workers, services, "
    "benchmarks. 'The thesis' in this help is the Ph.D. dissertation vista's methods come "
    "from, 'Reconstruction and Analysis of 3D Models for Autonomous Vehicles and "
    "Manufacturing Industry' (Department of Electrical and Information Engineering, 2022); "
    "'thesis 5.1' is its section 5.1, 'Table 6.1' its table.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
# `vista bench <service>` and `vista simulate <service>`: the older spellings of
# `vista <service> bench|simulate`, kept hidden for this release.
bench_app = typer.Typer(help="Older spellings of `vista <service> bench`.", no_args_is_help=True)
simulate_app = typer.Typer(
    help="Older spellings of `vista <service> simulate`.", no_args_is_help=True
)
api_app = typer.Typer(help="The supervisor's API under load.", no_args_is_help=True)
clients_app = typer.Typer(
    help="What the clients get: scenes, sync, the dashboard, run pages.", no_args_is_help=True
)
app.add_typer(users_cli.app, name="user")
app.add_typer(api_app, name="api")
app.add_typer(clients_app, name="clients")
app.add_typer(bench_app, name="bench", hidden=True, deprecated=True)
app.add_typer(simulate_app, name="simulate", hidden=True, deprecated=True)


@app.command()
def migrate(revision: str = typer.Option("head", help="Target revision.")) -> None:
    """Create or upgrade the database schema (VISTA_DATABASE_URL, default a SQLite file)."""
    from supervisor.migrate import current_revision, upgrade

    settings = get_settings()
    secure_data_dir(settings)
    url = settings.resolved_database_url
    try:
        upgrade(url, revision)
    except Exception as exc:  # shown to the user
        fail(f"migration failed on {_redact(url)}: {exc}")
    secure_data_dir(settings)
    typer.echo(f"database {_redact(url)} is at migration {current_revision(url)}")


def _redact(url: str) -> str:
    from sqlalchemy.engine import make_url

    return make_url(url).render_as_string(hide_password=True)


@app.command()
def serve(
    host: str | None = typer.Option(None, help="Default VISTA_HOST (127.0.0.1)."),
    port: int | None = typer.Option(None, help="Default VISTA_PORT (8000)."),
    workers: int | None = typer.Option(
        None, min=1, help="API processes; default VISTA_API_WORKERS (1)."
    ),
) -> None:
    """Serve the supervisor API (and, without a broker, the embedded job engine)."""
    from supervisor import serving
    from supervisor.migrate import SchemaOutOfDate, check_schema

    settings = get_settings()
    secure_data_dir(settings)
    try:
        created = check_schema(settings.resolved_database_url)
    except SchemaOutOfDate as exc:
        fail(str(exc))
    secure_data_dir(settings)
    if created:
        typer.echo(created)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    host, port = host or settings.host, port or settings.port
    processes = workers or settings.api_workers
    if processes > 1 and settings.resolved_database_url.startswith("sqlite"):
        typer.echo(
            "note: SQLite lets one process write at a time; with several API processes "
            "writes queue on its file lock. Use PostgreSQL to serve from several.",
            err=True,
        )
    engine = (
        f"dramatiq via {_redact(settings.broker_url)}"
        if settings.broker_url
        else (f"embedded, {settings.embedded_workers} worker processes")
    )
    typer.echo(
        f"vista supervisor on http://{host}:{port} with {processes} API process(es) "
        f"(database {_redact(settings.resolved_database_url)}; jobs {engine}); "
        f"API docs at http://{host}:{port}/docs"
    )
    try:
        serving.serve(host, port, processes=processes, access_log=settings.access_log)
    except OSError as exc:
        fail(f"cannot listen on {host}:{port}: {exc.strerror or exc}")


@app.command()
def worker(
    queues: str = typer.Option(None, help="Comma-separated queues; default all."),
    processes: int = typer.Option(1, min=1, help="Worker processes."),
    threads: int = typer.Option(1, min=1, help="Threads per process (jobs at once each)."),
) -> None:
    """Run Dramatiq workers for the given queues (needs VISTA_BROKER_URL)."""
    from supervisor.engine.registry import load_kinds
    from supervisor.engine.registry import queues as known_queues

    settings = get_settings()
    if not settings.broker_url:
        fail(
            "vista worker needs VISTA_BROKER_URL (redis://… or amqp://…); without a broker "
            "`vista serve` runs jobs itself"
        )
    load_kinds(settings.extra_job_kinds)
    available = known_queues()
    wanted = [q.strip() for q in queues.split(",") if q.strip()] if queues else available
    unknown = sorted(set(wanted) - set(available))
    if unknown:
        fail(f"unknown queue(s) {unknown}; the queues are {available}")
    args = [
        sys.executable,
        "-m",
        "dramatiq",
        "supervisor.worker_app",
        "--processes",
        str(processes),
        "--threads",
        str(threads),
        "--queues",
        *wanted,
    ]
    typer.echo(f"vista worker: queues {wanted}, {processes} process(es) x {threads} thread(s)")
    sys.stdout.flush()
    os.execv(sys.executable, args)


@api_app.command("bench")
def bench_api(
    out: Path = typer.Option(Path("bench-results/api.json"), help="Where to write the JSON."),
    clients: int = typer.Option(32, min=1, help="Concurrent clients writing judgments."),
    seconds: float = typer.Option(10.0, min=1, help="Duration of the write test per database."),
    defects: int = typer.Option(10_000, min=200, help="Defects in the paged inspection."),
    postgres_url: str = typer.Option(
        None, help="PostgreSQL URL for the second run; default VISTA_TEST_DATABASE_URL."
    ),
    api_workers: list[int] = typer.Option(
        [1, 2],
        min=1,
        help="API processes serving PostgreSQL, repeatable: a run for each count "
        "(SQLite is served by one).",
    ),
    sqlite_normal: bool = typer.Option(
        True, help="Also run SQLite with synchronous=NORMAL (the cost of durability)."
    ),
) -> None:
    """Judgment writes/s and latency with concurrent clients, and defect-page latency, on
    SQLite and PostgreSQL, each against a real `vista serve` process."""
    from benches.api import run_api_bench

    run_api_bench(
        out=out,
        clients=clients,
        seconds=seconds,
        defects=defects,
        postgres_url=postgres_url or os.environ.get("VISTA_TEST_DATABASE_URL"),
        api_workers=tuple(api_workers),
        sqlite_normal=sqlite_normal,
    )


@clients_app.command("bench")
def bench_clients(
    out: Path = typer.Option(Path("bench-results/clients.json"), help="Where to write the JSON."),
    points: int = typer.Option(2_500_000, min=10_000, help="Points of the stitched cloud."),
    scene_defects: int = typer.Option(1000, min=1, help="Defects in the scene's inspection."),
    sync_defects: int = typer.Option(10_000, min=1, help="Defects in the synced inspection."),
    frames: int = typer.Option(
        150, min=2, max=2000, help="Frames of the services' sample drive and sequence."
    ),
    real_data: Path = typer.Option(
        None,
        help="A folder of real data (e.g. ../shared/data): a KITTI raw drive with labels in it "
        "is tracked too, its scans drawn with every point.",
    ),
    only_perception: bool = typer.Option(
        False, "--only-perception", help="Only the services' results: scenes, run pages, player."
    ),
) -> None:
    """scene.glb export time and the Khronos validator's verdict (trimesh as the peer),
    sync from cursor 0 and after one change (paged GET /defects as the peer), and the
    dashboard's first meaningful paint in headless Chromium (a screenshot beside the JSON),
    against a real `vista serve` process; then every service's sample run on a `vista serve`
    with its engine: each job's glTF (seconds, MB, validator), each run page's first paint at
    1440 px (screenshots in run-pages/ beside the JSON) and a drive played with every point."""
    from benches.clients import run_clients_bench

    run_clients_bench(
        out=out,
        points=points,
        scene_defects=scene_defects,
        sync_defects=sync_defects,
        frames=frames,
        real_data=real_data,
        only_perception=only_perception,
    )


alias(bench_app, "api", bench_api, "api bench")
alias(bench_app, "clients", bench_clients, "clients bench")

for register in declared_hooks("CLI"):  # each service's commands, as the registry names them
    register(app, simulate_app, bench_app)


@app.command()
def demo(
    spacing_mm: float = typer.Option(
        0.2, min=0.1, max=0.5, help="Sensor sampling on the panels (0.1 = Gocator density, slower)."
    ),
    seed: int = typer.Option(0, help="Which simulated assembly."),
    timeout: float = typer.Option(900, min=10, help="Seconds to wait for the run."),
) -> None:
    """Simulate a curved cabin sidewall with seams out of tolerance and surface defects and
    run it through the whole chain (upload → calibrate → stitch → measure) on this
    installation, so its inspection list shows real findings."""
    from supervisor.demo import DEMO_USER, DemoError, run_demo

    settings = get_settings()
    try:
        outcome = run_demo(
            settings, spacing_mm=spacing_mm, seed=seed, timeout_s=timeout, say=typer.echo
        )
    except DemoError as exc:
        fail(str(exc))
    inspection, run, defects = outcome["inspection"], outcome["run"], outcome["defects"]
    measured = next(j for j in run["jobs"] if j["step"] == "measure")["result"]
    found = [d for d in defects if d["severity"] != "info"]
    typer.echo(
        f"\ninspection {inspection['id']} “{inspection['title']}”, run {run['id']}: "
        f"{counted(measured['panels'], 'panel')}, {counted(measured['seams'], 'seam')}, "
        f"{counted(measured['junctions'], 'junction')}; "
        f"{counted(len(found), 'defect')} out of tolerance, "
        f"{counted(len(defects) - len(found), 'seam')} within it"
    )
    limits = limits_of(Tolerances.model_validate(inspection["tolerances"]))
    for d in sorted(found, key=lambda d: (d["type"], d["id"])):
        m = d["measurements"]
        typer.echo(
            f"  #{d['id']:<5} "
            + finding_line(d["type"], m["value"], m.get("panels"), limits)
            + f" {d['severity']:<8} confidence {d['confidence']:.2f}"
        )
    url = f"http://{settings.host}:{settings.port}"
    typer.echo(
        f"\nsimulated data and its ground truth: {outcome['folder']}\n"
        f"review it: `vista serve` (or `make run`), then open the dashboard at {url}/ and "
        f"sign in as {DEMO_USER} with the password {outcome['password']} (new at each demo "
        f"run; shown only here): inspection {inspection['id']} shows the "
        f"scene, the defects and the runs.\n"
        f"the API: {url}/docs (works offline); GET /api/v1/defects?inspection={inspection['id']}"
    )


@app.command()
def precompile() -> None:
    """Compile the services' numba kernels into numba's on-disk cache (`make install` does;
    about a minute on 2 cores), so that no user's first measurement or odometry run waits
    for the compiler: each service runs a small job of its own. Later runs load the cache
    in a fraction of a second; a changed source file is compiled again at its first use."""
    import time

    from numba import config

    where = config.CACHE_DIR or "__pycache__ beside each source file, or the user's cache"
    typer.echo(f"numba's cache: {where}")
    for warm_up in declared_hooks("PRECOMPILE"):
        service = warm_up.__module__.split(".")[1]
        started = time.perf_counter()
        warm_up()
        typer.echo(f"{service}: ready in {time.perf_counter() - started:.1f} s")


unwrap_help(app)  # last: every command is registered by now


if __name__ == "__main__":
    app()
