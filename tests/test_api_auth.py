from __future__ import annotations

from tests.conftest import auth


def test_sign_in_gives_a_token_that_identifies_the_user(client, tokens):
    response = client.post(
        "/api/v1/auth/token", json={"username": "ines", "password": "inspector-password"}
    )
    assert response.status_code == 200
    token = response.json()["access_token"]
    me = client.get("/api/v1/me", headers=auth(token)).json()
    assert me["username"] == "ines" and me["role"] == "inspector" and me["token_kind"] == "session"


def test_wrong_password_and_unknown_user_are_refused_alike(client, tokens):
    wrong = client.post("/api/v1/auth/token", json={"username": "ines", "password": "nope"})
    unknown = client.post("/api/v1/auth/token", json={"username": "nobody", "password": "nope"})
    assert wrong.status_code == unknown.status_code == 401
    assert wrong.headers["content-type"] == "application/problem+json"
    assert wrong.json()["detail"] == unknown.json()["detail"]


def test_missing_or_forged_token_is_401_problem(client, tokens):
    missing = client.get("/api/v1/inspections")
    forged = client.get("/api/v1/inspections", headers=auth("vst_forged"))
    for response in (missing, forged):
        assert response.status_code == 401
        assert response.headers["www-authenticate"] == "Bearer"
        assert response.json()["detail"]


def test_tokens_are_stored_hashed(client, tokens, runtime):
    from sqlalchemy import select

    from supervisor.models import ApiToken, User

    with runtime.db.read() as session:
        stored = session.scalars(select(ApiToken.token_sha256)).all()
        hashes = session.scalars(select(User.password_hash).where(User.password_hash.is_not(None)))
        assert all(h.startswith("$argon2") for h in hashes)
    assert tokens["admin"] not in stored and len(stored) == len(tokens)


def test_admin_creates_device_user_and_token(client, tokens):
    created = client.post(
        "/api/v1/users", json={"username": "hl2", "role": "device"}, headers=auth(tokens["admin"])
    )
    assert created.status_code == 201, created.text
    user_id = created.json()["id"]
    token = client.post(
        f"/api/v1/users/{user_id}/tokens",
        json={"name": "hololens cargo", "kind": "device"},
        headers=auth(tokens["admin"]),
    ).json()["token"]
    me = client.get("/api/v1/me", headers=auth(token)).json()
    assert me == {"id": user_id, "username": "hl2", "role": "device", "token_kind": "device"}


def test_only_admins_manage_users(client, tokens):
    for role in ("inspector", "viewer", "device"):
        response = client.post(
            "/api/v1/users",
            json={"username": f"x-{role}", "role": "viewer", "password": "long-enough"},
            headers=auth(tokens[role]),
        )
        assert response.status_code == 403, role
        assert role in response.json()["detail"]
        assert client.get("/api/v1/users", headers=auth(tokens[role])).status_code == 403
        assert (
            client.post(
                "/api/v1/users/1/tokens", json={"name": "t"}, headers=auth(tokens[role])
            ).status_code
            == 403
        )
    listed = client.get("/api/v1/users", headers=auth(tokens["admin"])).json()["items"]
    assert {u["username"] for u in listed} == {"ada", "ines", "ivan", "vic", "hololens-1"}


def test_people_need_a_password_and_names_are_unique(client, tokens):
    headers = auth(tokens["admin"])
    no_password = client.post(
        "/api/v1/users", json={"username": "p", "role": "inspector"}, headers=headers
    )
    assert no_password.status_code == 422 and "password" in no_password.json()["detail"]
    taken = client.post(
        "/api/v1/users",
        json={"username": "ines", "role": "viewer", "password": "long-enough"},
        headers=headers,
    )
    assert taken.status_code == 409


def test_health_and_readiness(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz").json()
    assert ready["status"] == "ready" and ready["engine"] == "embedded"
