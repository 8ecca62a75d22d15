"""Defects written the way a measuring job writes them (rows plus change-log entries)."""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import insert, select

from supervisor.models import Change, Defect, Job, Run

TYPES = ("gap", "step", "scratch", "dent")


def seed_defects(
    runtime, inspection_id: int, count: int, *, run_id=None, uncertain: tuple[int, ...] = ()
) -> list[int]:
    """``count`` defects: types cycle gap, step, scratch, dent; defect i sits at x = i mm;
    those in ``uncertain`` were measured within 2σ of their limit (σ 0.1 mm)."""
    rows = [
        {
            "inspection_id": inspection_id,
            "run_id": run_id,
            "type": TYPES[i % 4],
            "status": "open" if i % 5 else "resolved",
            "value_mm": 1.0 + i / 100,
            "tolerance_mm": 1.0,
            "measurements": {"tolerance_state": "uncertain", "sigma_mm": 0.1}
            if i in uncertain
            else {},
            "location_mm": [float(i), 0.0, 0.0],
            "normal": [0.0, 0.0, 1.0],
            "extent_mm": 3.0,
            "severity": "info" if i % 3 == 0 else "minor",
            "confidence": 0.9,
            "source": "job",
        }
        for i in range(count)
    ]
    with runtime.db.write() as session:
        before = session.scalar(select(Defect.id).order_by(Defect.id.desc()).limit(1)) or 0
        session.execute(insert(Defect), rows)
        ids = list(session.scalars(select(Defect.id).where(Defect.id > before).order_by(Defect.id)))
        session.execute(
            insert(Change),
            [
                {"entity": "defect", "entity_id": i, "op": "create", "inspection_id": inspection_id}
                for i in ids
            ],
        )
        return ids


def seed_warning(runtime, inspection_id: int, warning: str, unmeasured_seams: int) -> int:
    """A succeeded defects.measure job of a run of the inspection whose result carries
    ``warning`` and ``unmeasured_seams``, as a measurement that left seams unmeasured ends;
    its id."""
    with runtime.db.write() as session:
        run = Run(inspection_id=inspection_id, name="measure")
        session.add(run)
        session.flush()
        job = Job(
            run_id=run.id,
            inspection_id=inspection_id,
            step="measure",
            position=0,
            kind="defects.measure",
            queue="defects",
            status="succeeded",
            result={"warning": warning, "unmeasured_seams": unmeasured_seams},
        )
        session.add(job)
        session.flush()
        return job.id


def measure_uploaded(http, inspection: int, cloud: Path) -> dict:
    """``cloud`` (a PLY) uploaded to the inspection and a defects.measure run started on it,
    through the API with ``http`` (an httpx client with a token); the run as created."""
    artifact = http.post(
        f"/api/v1/inspections/{inspection}/artifacts",
        params={"kind": "cloud", "name": cloud.name},
        content=cloud.read_bytes(),
        headers={"content-type": "application/x-ply"},
    ).json()["id"]
    return http.post(
        f"/api/v1/inspections/{inspection}/runs",
        json={"steps": [{"name": "measure", "kind": "defects.measure", "inputs": [artifact]}]},
    ).json()


def record_measurement(
    runtime, inspection_id: int, findings: list, *, bounds_mm: list | None = None
) -> tuple[int, int]:
    """A succeeded defects.measure job of a new run that found ``findings`` (NewDefects)
    in a cloud within ``bounds_mm``, stored as the engine stores a job's outputs (the
    findings, then the lineage step); (run id, job id)."""
    from supervisor.defects.lineage import supersede
    from supervisor.defects.service import record_defect

    with runtime.db.write() as session:
        run = Run(inspection_id=inspection_id, name="measure")
        session.add(run)
        session.flush()
        job = Job(
            run_id=run.id,
            inspection_id=inspection_id,
            step="measure",
            position=0,
            kind="defects.measure",
            queue="defects",
            status="succeeded",
            result={"cloud_bounds_mm": bounds_mm} if bounds_mm is not None else {},
        )
        session.add(job)
        session.flush()
        for finding in findings:
            record_defect(
                session,
                finding,
                inspection_id=inspection_id,
                source="job",
                run_id=run.id,
                job_id=job.id,
            )
        supersede(session, job_id=job.id)
        return run.id, job.id
