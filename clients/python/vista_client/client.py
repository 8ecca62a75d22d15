"""An httpx client for the whole vista supervisor API (``/api/v1``).

Every method is one request (list methods follow ``next_cursor`` for you); errors raise
``VistaError`` carrying the server's problem document and its human sentence.
"""

from __future__ import annotations

import json
import mimetypes
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

API = "/api/v1"
PLY_MEDIA_TYPE = "application/x-ply"


class VistaError(Exception):
    """The server refused a request: ``status`` and the problem's ``detail`` sentence."""

    def __init__(self, status: int, detail: str, problem: dict | None = None) -> None:
        super().__init__(f"{status}: {detail}")
        self.status = status
        self.detail = detail
        self.problem = problem or {}


class VistaClient:
    """``VistaClient("http://127.0.0.1:8000", token=...)``, or ``sign_in`` after creating it.

    ``transport`` is passed to httpx (tests use it to drop responses on the floor).
    """

    def __init__(
        self,
        base_url: str,
        token: str | None = None,
        *,
        timeout_s: float = 30.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        self.base_url = base_url.rstrip("/")
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout_s, transport=transport)
        self.token = token

    # -- plumbing ----------------------------------------------------------------------

    @property
    def token(self) -> str | None:
        return self._token

    @token.setter
    def token(self, value: str | None) -> None:
        self._token = value
        if value:
            self._http.headers["Authorization"] = f"Bearer {value}"
        else:
            self._http.headers.pop("Authorization", None)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> VistaClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """One API request; raises ``VistaError`` on a 4xx/5xx answer."""
        response = self._http.request(method, API + path, **kwargs)
        if response.status_code >= 400:
            try:
                problem = response.json()
                detail = problem.get("detail") or problem.get("title") or response.text
            except (json.JSONDecodeError, AttributeError):
                problem, detail = None, response.text or response.reason_phrase
            raise VistaError(response.status_code, detail, problem)
        return response

    def _json(self, method: str, path: str, **kwargs: Any) -> Any:
        return self.request(method, path, **kwargs).json()

    def _pages(self, path: str, params: dict | None = None) -> Iterator[dict]:
        query = {k: v for k, v in (params or {}).items() if v is not None}
        while True:
            page = self._json("GET", path, params=query)
            yield from page["items"]
            if not page.get("next_cursor"):
                return
            query["cursor"] = page["next_cursor"]

    # -- auth and users ----------------------------------------------------------------

    def sign_in(self, username: str, password: str) -> str:
        """Exchange a password for a session token (kept for the following requests)."""
        answer = self._json(
            "POST", "/auth/token", json={"username": username, "password": password}
        )
        self.token = answer["access_token"]
        return self.token

    def me(self) -> dict:
        return self._json("GET", "/me")

    def create_user(self, username: str, role: str, password: str | None = None) -> dict:
        body = {"username": username, "role": role}
        if password is not None:
            body["password"] = password
        return self._json("POST", "/users", json=body)

    def users(self) -> Iterator[dict]:
        return self._pages("/users")

    def create_token(
        self, user_id: int, name: str, *, kind: str = "device", ttl_hours: float | None = None
    ) -> str:
        """Issue a token for a user (admins): ``kind="device"`` for a headset."""
        body = {"name": name, "kind": kind, "ttl_hours": ttl_hours}
        return self._json("POST", f"/users/{user_id}/tokens", json=body)["token"]

    # -- inspections, artifacts, runs, jobs --------------------------------------------

    def inspections(self) -> Iterator[dict]:
        return self._pages("/inspections")

    def inspection(self, inspection_id: int) -> dict:
        return self._json("GET", f"/inspections/{inspection_id}")

    def create_inspection(self, title: str, area: str, **fields: Any) -> dict:
        return self._json("POST", "/inspections", json={"title": title, "area": area, **fields})

    def update_inspection(self, inspection_id: int, **fields: Any) -> dict:
        return self._json("PATCH", f"/inspections/{inspection_id}", json=fields)

    def tolerance_sets(self) -> Iterator[dict]:
        return self._pages("/tolerance-sets")

    def create_tolerance_set(self, name: str, tolerances: dict, description: str = "") -> dict:
        """Name a set of limits to apply to inspections."""
        body = {"name": name, "tolerances": tolerances, "description": description}
        return self._json("POST", "/tolerance-sets", json=body)

    def apply_tolerance_set(self, inspection_id: int, set_id: int) -> dict:
        """Give the inspection the set's limits; returns the inspection."""
        return self._json(
            "POST", f"/inspections/{inspection_id}/tolerance-set", json={"set_id": set_id}
        )

    def upload(self, inspection_id: int, path: Path, *, kind: str, name: str | None = None) -> dict:
        """Upload a file as an artifact (PLY clouds are checked by the server)."""
        path = Path(path)
        media_type = (
            PLY_MEDIA_TYPE
            if path.suffix.lower() == ".ply"
            else mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        )
        with open(path, "rb") as handle:
            return self._json(
                "POST",
                f"/inspections/{inspection_id}/artifacts",
                params={"kind": kind, "name": name or path.name},
                content=handle,
                headers={"Content-Type": media_type},
            )

    def artifacts(self, inspection_id: int) -> Iterator[dict]:
        return self._pages(f"/inspections/{inspection_id}/artifacts")

    def download(self, inspection_id: int, artifact_id: int) -> bytes:
        return self.request(
            "GET", f"/inspections/{inspection_id}/artifacts/{artifact_id}/content"
        ).content

    def create_run(self, inspection_id: int, steps: list[dict], name: str = "") -> dict:
        return self._json(
            "POST", f"/inspections/{inspection_id}/runs", json={"name": name, "steps": steps}
        )

    def runs(self, inspection_id: int) -> Iterator[dict]:
        return self._pages(f"/inspections/{inspection_id}/runs")

    def job(self, job_id: int) -> dict:
        return self._json("GET", f"/jobs/{job_id}")

    def job_events(self, job_id: int) -> Iterator[tuple[str, dict]]:
        """Live ``(event, data)`` pairs of a job: ``progress`` …, then ``end``."""
        with self._http.stream("GET", f"{API}/jobs/{job_id}/events", timeout=None) as response:
            if response.status_code >= 400:
                response.read()
                raise VistaError(response.status_code, response.json().get("detail", ""))
            event = None
            for line in response.iter_lines():
                if line.startswith("event: "):
                    event = line[len("event: ") :]
                elif line.startswith("data: ") and event:
                    yield event, json.loads(line[len("data: ") :])
                    if event == "end":
                        return

    # -- defects, judgments, feedback ---------------------------------------------------

    def defects(self, inspection_id: int | None = None, **filters: Any) -> Iterator[dict]:
        """Current defects in id order; filters: ``run``, ``type``, ``status``,
        ``severity``, ``history=True`` (also findings a later measurement ended)."""
        return self._pages("/defects", {"inspection": inspection_id, **filters, "limit": 500})

    def defect(self, defect_id: int) -> dict:
        return self._json("GET", f"/defects/{defect_id}")

    def judge(
        self, defect_id: int, verdict: str, *, new_type: str | None = None, comment: str = ""
    ) -> dict:
        """Set your judgment (``confirmed``, ``rejected``, ``reclassified`` with
        ``new_type``, ``uncertain``); returns it with the defect's consensus."""
        body = {"verdict": verdict, "comment": comment}
        if new_type is not None:
            body["new_type"] = new_type
        return self._json("PUT", f"/defects/{defect_id}/judgments/me", json=body)

    def report_defect(
        self, inspection_id: int, type: str, location_mm: list[float], **fields: Any
    ) -> dict:
        """Report a finding by hand: ``severity``, ``value_mm``, ``normal``, ``note``, …"""
        body = {"inspection_id": inspection_id, "type": type, "location_mm": location_mm}
        return self._json("POST", "/defects", json={**body, **fields})

    def annotate(self, defect_id: int, text: str) -> dict:
        """Add a note to a finding; returns the finding."""
        return self._json("POST", f"/defects/{defect_id}/notes", json={"text": text})

    def set_status(self, defect_id: int, status: str, *, reason: str = "") -> dict:
        """Resolve, dismiss (with a ``reason``) or reopen a defect."""
        return self._json(
            "PATCH", f"/defects/{defect_id}", json={"status": status, "reason": reason}
        )

    def defect_history(self, defect_id: int) -> dict:
        """The defect's line across measurements, with every judgment made along it."""
        return self._json("GET", f"/defects/{defect_id}/history")

    def judgments(self, defect_id: int) -> dict:
        return self._json("GET", f"/defects/{defect_id}/judgments")

    def feedback(self, inspection_id: int | None = None, *, min_reviews: int = 3) -> dict:
        params = {"min_reviews": min_reviews}
        if inspection_id is not None:
            params["inspection"] = inspection_id
        return self._json("GET", "/feedback", params=params)

    # -- sync and scene -----------------------------------------------------------------

    def sync(
        self, inspection_id: int, since: str | None = None, *, limit: int | None = None
    ) -> dict:
        """One page of what changed since ``since`` (None: everything)."""
        params: dict[str, Any] = {"inspection": inspection_id}
        if since is not None:
            params["since"] = since
        if limit is not None:
            params["limit"] = limit
        return self._json("GET", "/sync", params=params)

    def push_judgments(self, items: list[dict]) -> dict:
        """POST a batch of offline judgments (see ``Headset``)."""
        return self._json("POST", "/sync/judgments", json={"items": items})

    def scene(
        self, inspection_id: int, *, etag: str | None = None, points: int | None = None
    ) -> tuple[bytes | None, str]:
        """(GLB bytes, ETag); (None, ETag) when ``etag`` is still current."""
        headers = {"If-None-Match": etag} if etag else {}
        params = {"points": points} if points else {}
        response = self.request(
            "GET", f"/inspections/{inspection_id}/scene.glb", headers=headers, params=params
        )
        if response.status_code == 304:
            return None, response.headers["etag"]
        return response.content, response.headers["etag"]
