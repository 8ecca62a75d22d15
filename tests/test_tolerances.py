"""Tolerances edited without losing any: a PATCH changes only the limits it names (null: a
limit's default), the answer shows every limit in force; named tolerance sets, applied to
inspections with their name and version kept and audited."""

from __future__ import annotations

from contract.tolerances import Limits, merge_tolerances
from tests.conftest import auth

SURFACE = {"dent_depth_mm": 0.5, "scratch_depth_mm": 0.3}


def _given(section: dict | None) -> dict:
    """A section of the answer's tolerances without the limits it leaves to the defaults."""
    return {k: v for k, v in (section or {}).items() if v is not None}


def _inspection(client, token: str, **fields) -> dict:
    body = {"title": "lining", "area": "cabin", **fields}
    response = client.post("/api/v1/inspections", json=body, headers=auth(token))
    assert response.status_code == 201, response.text
    return response.json()


def test_merge_keeps_what_is_not_named_and_null_restores_a_default() -> None:
    stored = {"gap_mm": {"min": 0.8, "max": 2.0}, "surface": SURFACE}
    assert merge_tolerances(stored, {"gap_mm": {"max": 2.5}}) == {
        "gap_mm": {"min": 0.8, "max": 2.5},
        "surface": SURFACE,
    }
    assert merge_tolerances(stored, {"surface": {"dent_depth_mm": None}}) == {
        "gap_mm": {"min": 0.8, "max": 2.0},
        "surface": {"scratch_depth_mm": 0.3},
    }
    assert merge_tolerances(stored, {"gap_mm": None}) == {"surface": SURFACE}
    assert merge_tolerances(stored, None) == {}


def test_a_patch_of_one_limit_keeps_the_others(client, tokens) -> None:
    owner = auth(tokens["inspector"])
    made = _inspection(client, tokens["inspector"], tolerances={"surface": SURFACE})
    url = f"/api/v1/inspections/{made['id']}"
    patched = client.patch(url, json={"tolerances": {"gap_mm": {"max": 2.5}}}, headers=owner)
    assert patched.status_code == 200, patched.text
    body = patched.json()
    assert _given(body["tolerances"]["surface"]) == SURFACE  # it reset these to null before
    assert body["limits"]["dent_depth_mm"] == 0.5 and body["limits"]["gap_max_mm"] == 2.5
    assert body["limits"]["gap_min_mm"] == Limits.gap_min_mm  # every limit in force
    restored = client.patch(
        url, json={"tolerances": {"surface": {"dent_depth_mm": None}}}, headers=owner
    ).json()
    assert restored["limits"]["dent_depth_mm"] == Limits.dent_depth_mm
    assert restored["limits"]["scratch_depth_mm"] == 0.3
    # the range is judged once merged: max below the stored min is refused, naming it
    narrow = client.patch(
        url, json={"tolerances": {"gap_mm": {"min": 2.0, "max": 1.0}}}, headers=owner
    )
    assert narrow.status_code == 422 and "tolerances.gap_mm" in narrow.json()["detail"]
    assert client.get(url, headers=owner).json()["limits"]["gap_max_mm"] == 2.5  # unchanged
    other = client.patch(
        url, json={"tolerances": {"step_mm": {"max": 1.0}}}, headers=auth(tokens["inspector2"])
    )
    assert other.status_code == 403
    assert client.patch(url, json={"tolerances": None}, headers=owner).json()["tolerances"] == {
        "gap_mm": None,
        "step_mm": None,
        "parallelism_mm": None,
        "mismatch_mm": None,
        "surface": None,
        "profile_mm": None,
    }


def test_named_sets_applied_with_their_name_and_version(client, tokens) -> None:
    owner, other = auth(tokens["inspector"]), auth(tokens["inspector2"])
    schema = client.get("/api/v1/tolerances/schema", headers=auth(tokens["viewer"])).json()
    assert "surface" in schema["schema"]["properties"]
    assert schema["defaults"]["surface"]["dent_depth_mm"] == Limits.dent_depth_mm
    made = client.post(
        "/api/v1/tolerance-sets",
        json={"name": "A320 lining", "tolerances": {"gap_mm": {"max": 2.0}, "surface": SURFACE}},
        headers=other,
    )
    assert made.status_code == 201, made.text
    lining = made.json()
    assert lining["version"] == 1
    twice = client.post(
        "/api/v1/tolerance-sets", json={"name": "A320 lining", "tolerances": {}}, headers=owner
    )
    assert twice.status_code == 409 and "A320 lining" in twice.json()["detail"]
    set_url = f"/api/v1/tolerance-sets/{lining['id']}"
    assert client.patch(set_url, json={"description": "x"}, headers=owner).status_code == 403
    edited = client.patch(
        set_url, json={"tolerances": {"step_mm": {"max": 0.8}}}, headers=other
    ).json()
    assert edited["version"] == 2 and _given(edited["tolerances"]["surface"]) == SURFACE

    inspection = _inspection(client, tokens["inspector"])["id"]
    apply_url = f"/api/v1/inspections/{inspection}/tolerance-set"
    refused = client.post(apply_url, json={"set_id": lining["id"]}, headers=other)
    assert refused.status_code == 403  # the set's maker, not the inspection's owner
    applied = client.post(apply_url, json={"set_id": lining["id"]}, headers=owner)
    assert applied.status_code == 200, applied.text
    body = applied.json()
    assert body["tolerance_set"] == {
        "id": lining["id"],
        "name": "A320 lining",
        "version": 2,
        "edited": False,
    }
    assert body["limits"]["step_max_mm"] == 0.8 and body["limits"]["dent_depth_mm"] == 0.5
    events = client.get("/api/v1/audit", params={"inspection": inspection}, headers=owner).json()[
        "items"
    ]
    event = next(e for e in events if e["action"] == "apply_tolerance_set")
    assert event["after"]["tolerance_set"]["name"] == "A320 lining"
    assert event["after"]["tolerance_set"]["version"] == 2
    hand = client.patch(
        f"/api/v1/inspections/{inspection}",
        json={"tolerances": {"step_mm": {"max": 0.9}}},
        headers=owner,
    ).json()
    assert hand["tolerance_set"]["edited"] is True and hand["limits"]["step_max_mm"] == 0.9
    assert client.delete(set_url, headers=other).status_code == 204
    kept = client.get(f"/api/v1/inspections/{inspection}", headers=owner).json()
    assert kept["tolerance_set"]["name"] == "A320 lining" and kept["limits"]["dent_depth_mm"] == 0.5
