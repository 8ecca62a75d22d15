from __future__ import annotations

from tests.conftest import auth

NEW = {"title": "A320 MSN 1234 cabin", "aircraft": "A320", "serial": "1234", "area": "cabin"}


def test_crud_round_trip(client, tokens):
    headers = auth(tokens["inspector"])
    created = client.post(
        "/api/v1/inspections",
        json={**NEW, "tolerances": {"gap_mm": {"min": 0.5, "max": 2.0}, "step_mm": {"max": 0.5}}},
        headers=headers,
    )
    assert created.status_code == 201, created.text
    body = created.json()
    assert created.headers["location"] == f"/api/v1/inspections/{body['id']}"
    assert body["tolerances"]["gap_mm"] == {"min": 0.5, "max": 2.0} and body["status"] == "planned"
    patched = client.patch(
        f"/api/v1/inspections/{body['id']}", json={"status": "scanning"}, headers=headers
    ).json()
    assert patched["status"] == "scanning" and patched["title"] == NEW["title"]
    assert (
        client.get(f"/api/v1/inspections/{body['id']}", headers=auth(tokens["viewer"])).json()
        == patched
    )
    assert client.delete(f"/api/v1/inspections/{body['id']}", headers=headers).status_code == 204
    assert client.get(f"/api/v1/inspections/{body['id']}", headers=headers).status_code == 404


def test_viewers_and_devices_cannot_change_inspections(client, tokens):
    for role in ("viewer", "device"):
        response = client.post("/api/v1/inspections", json=NEW, headers=auth(tokens[role]))
        assert response.status_code == 403


def test_bad_input_is_a_sentence_and_stores_nothing(client, tokens):
    headers = auth(tokens["inspector"])
    cases = [
        ({**NEW, "colour": "red"}, "colour: is not a known field"),
        ({**NEW, "area": "   "}, "area"),  # free text, but not blank
        ({"title": "no area"}, "area: is required"),
        ({**NEW, "tolerances": {"gap_mm": {"min": -1}}}, "tolerances.gap_mm.min"),
        ({**NEW, "tolerances": {"flatness": 1}}, "tolerances.flatness: is not a known field"),
        (
            {**NEW, "tolerances": {"gap_mm": {"min": 3, "max": 0.5}}},
            "tolerances.gap_mm: min (3) must be below max (0.5)",
        ),
        (
            {**NEW, "tolerances": {"step_mm": {"max": 0}}},
            "tolerances.step_mm.max: must be greater than 0.",
        ),
        ({**NEW, "tolerances": "tight"}, "tolerances: must be an object of named fields"),
        ({**NEW, "area": "x" * 65}, "area: must have at most 64 characters"),
        ([1, 2], "the request body: must be an object of named fields"),
    ]
    for body, expected in cases:
        response = client.post("/api/v1/inspections", json=body, headers=headers)
        assert response.status_code == 422, body
        assert response.headers["content-type"] == "application/problem+json"
        assert expected in response.json()["detail"], response.json()["detail"]
    not_json = client.post(
        "/api/v1/inspections",
        content=b"{nope",
        headers={**headers, "content-type": "application/json"},
    )
    assert not_json.status_code == 422
    assert not_json.json()["detail"].startswith("The request body is not valid JSON (")
    assert "at character 1" in not_json.json()["detail"]
    assert client.get("/api/v1/inspections", headers=headers).json()["items"] == []


def test_unknown_ids_are_404_problems(client, tokens):
    headers = auth(tokens["admin"])
    for method, path in [
        ("GET", "/api/v1/inspections/999"),
        ("PATCH", "/api/v1/inspections/999"),
        ("DELETE", "/api/v1/inspections/999"),
        ("GET", "/api/v1/defects/999"),
        ("GET", "/api/v1/jobs/999"),
        ("GET", "/api/v1/runs/999"),
        ("GET", "/api/v1/inspections/999/artifacts"),
        ("GET", "/api/v1/no/such/route"),
    ]:
        response = client.request(
            method, path, headers=headers, json={} if method == "PATCH" else None
        )
        assert response.status_code == 404, (method, path)
        assert response.headers["content-type"] == "application/problem+json"
        assert response.json()["detail"].endswith(".")


def test_cursor_pagination_visits_every_inspection_once(client, tokens):
    headers = auth(tokens["inspector"])
    for number in range(7):
        client.post("/api/v1/inspections", json={**NEW, "title": f"t{number}"}, headers=headers)
    seen, cursor = [], None
    while True:
        page = client.get(
            "/api/v1/inspections",
            params={"limit": 3, **({"cursor": cursor} if cursor else {})},
            headers=headers,
        ).json()
        seen += [item["title"] for item in page["items"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert seen == [f"t{n}" for n in range(7)]
    bad = client.get("/api/v1/inspections", params={"cursor": "garbage!"}, headers=headers)
    assert bad.status_code == 400


def test_idempotency_key_replays_and_refuses_reuse(client, tokens):
    headers = {**auth(tokens["inspector"]), "Idempotency-Key": "create-cabin-1"}
    first = client.post("/api/v1/inspections", json=NEW, headers=headers)
    again = client.post("/api/v1/inspections", json=NEW, headers=headers)
    assert first.status_code == again.status_code == 201
    assert again.json() == first.json() and again.headers["idempotent-replayed"] == "true"
    other = client.post("/api/v1/inspections", json={**NEW, "title": "other"}, headers=headers)
    assert other.status_code == 422 and "Idempotency-Key" in other.json()["detail"]
    # Keys belong to a user: the same key from someone else is a new request.
    theirs = client.post(
        "/api/v1/inspections",
        json=NEW,
        headers={**auth(tokens["inspector2"]), "Idempotency-Key": "create-cabin-1"},
    )
    assert theirs.status_code == 201 and theirs.json()["id"] != first.json()["id"]
    assert len(client.get("/api/v1/inspections", headers=headers).json()["items"]) == 2


def test_a_change_of_tolerances_judges_the_measured_findings_again(client, tokens, runtime):
    """A step of −0.8 mm over a 0.5 mm limit is `major`; a limit of 1 mm makes it a
    measurement within tolerance, in the same request, its limit the new one and the change
    in the log; a gap stored without its seam's range is marked stale instead; a finding
    added by hand keeps its judgment."""
    from supervisor.models import Defect

    headers = auth(tokens["inspector"])
    inspection = client.post("/api/v1/inspections", json=NEW, headers=headers).json()["id"]
    measured = {"location_mm": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0], "confidence": 0.9}
    with runtime.db.write() as session:
        rows = [
            Defect(inspection_id=inspection, type="step", value_mm=-0.8, tolerance_mm=0.5,
                   severity="major", source="job", measurements={"value": -0.8, "unit": "mm", "tolerance": 0.5}, **measured),
            Defect(inspection_id=inspection, type="gap", value_mm=3.4, tolerance_mm=3.0,
                   severity="minor", source="job", measurements={"value": 3.4, "unit": "mm", "tolerance": 3.0}, **measured),
            Defect(inspection_id=inspection, type="step", value_mm=0.9, tolerance_mm=0.5,
                   severity="major", source="manual", measurements={}, **measured),
        ]  # fmt: skip
        session.add_all(rows)
        session.flush()
        step, gap, manual = (r.id for r in rows)
    cursor = client.get("/api/v1/sync", params={"inspection": inspection}, headers=headers)
    tolerances = {"step_mm": {"max": 1.0}, "gap_mm": {"min": 0.5, "max": 6.0}}
    patched = client.patch(
        f"/api/v1/inspections/{inspection}", json={"tolerances": tolerances}, headers=headers
    )
    assert patched.status_code == 200, patched.text

    def defect(ident: int) -> dict:
        return client.get(f"/api/v1/defects/{ident}", headers=headers).json()

    assert defect(step)["severity"] == "info" and defect(step)["tolerance_mm"] == 1.0
    assert defect(step)["measurements"]["tolerance"] == 1.0
    assert "re-run the measurement" in defect(gap)["measurements"]["stale"]
    assert defect(gap)["severity"] == "minor"  # not judged by a guess
    assert defect(manual)["severity"] == "major" and defect(manual)["tolerance_mm"] == 0.5
    synced = client.get(
        "/api/v1/sync",
        params={"inspection": inspection, "since": cursor.json()["next_cursor"]},
        headers=headers,
    ).json()
    assert {d["id"] for d in synced["defects"]} == {step, gap}
    step_row = next(d for d in synced["defects"] if d["id"] == step)
    assert step_row["tolerance"] == 1.0 and step_row["severity"] == "info"


def test_a_finding_within_two_sigma_of_a_new_limit_turns_uncertain(client, tokens, runtime):
    """A step measured with its 1σ is judged out, within or uncertain: a limit it lies
    within 2σ of makes it uncertain, with the advice its numbers give, in the API, the
    sync and the scene's extras; a limit far from it judges it again."""
    from supervisor.models import Defect

    headers = auth(tokens["inspector"])
    inspection = client.post("/api/v1/inspections", json=NEW, headers=headers).json()["id"]
    with runtime.db.write() as session:
        row = Defect(
            inspection_id=inspection, type="step", value_mm=-0.8, tolerance_mm=0.5,
            severity="major", source="job", location_mm=[0.0, 0.0, 0.0], normal=[0.0, 0.0, 1.0],
            confidence=0.99,
            measurements={"value": -0.8, "unit": "mm", "tolerance": 0.5, "sigma_mm": 0.05,
                          "tolerance_state": "out", "spacing_mm": 0.4},
        )  # fmt: skip
        session.add(row)
        session.flush()
        step = row.id

    def judged(step_max_mm: float) -> dict:
        patched = client.patch(
            f"/api/v1/inspections/{inspection}",
            json={"tolerances": {"step_mm": {"max": step_max_mm}}},
            headers=headers,
        )
        assert patched.status_code == 200, patched.text
        return client.get(f"/api/v1/defects/{step}", headers=headers).json()

    assert client.get(f"/api/v1/defects/{step}", headers=headers).json()["tolerance_state"] == "out"
    near = judged(0.75)  # 0.05 mm from the limit: within 2σ (0.1 mm)
    assert near["tolerance_state"] == "uncertain" and near["severity"] == "minor"
    assert "re-scan at ≤ 0.20 mm spacing" in near["measurements"]["advice"]
    synced = client.get("/api/v1/sync", params={"inspection": inspection}, headers=headers)
    row = next(d for d in synced.json()["defects"] if d["id"] == step)
    assert row["tolerance_state"] == "uncertain" and row["measurements"]["advice"]
    within = judged(1.2)
    assert within["tolerance_state"] == "within" and within["severity"] == "info"
    assert "advice" not in within["measurements"]
