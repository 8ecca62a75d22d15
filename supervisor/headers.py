"""Security headers on every response (a pure ASGI middleware: no per-request task).

- ``X-Content-Type-Options: nosniff``: a browser never runs an uploaded file it was told
  is data (an artifact download keeps its declared type).
- ``Content-Security-Policy``: scripts only from vista itself; no framing anywhere
  (``frame-ancestors 'none'``, and ``X-Frame-Options`` for older browsers). The dashboard
  sets element styles and three.js reads the scene through ``blob:``/``data:`` URLs, so
  those are allowed; the offline API docs (/docs, /redoc) start with an inline script.
- ``Referrer-Policy: no-referrer``: a link out never carries an inspection's URL.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

_POLICY = (
    "default-src 'self'; script-src 'self'{inline}; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'self' data: blob:; worker-src 'self' blob:; "
    "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)
_COMMON = [
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
    (b"cross-origin-opener-policy", b"same-origin"),
]
_STRICT = [*_COMMON, (b"content-security-policy", _POLICY.format(inline="").encode())]
_DOCS = [
    *_COMMON,
    (b"content-security-policy", _POLICY.format(inline=" 'unsafe-inline'").encode()),
]
DOCS_PATHS = ("/docs", "/redoc")


class SecurityHeaders:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = _DOCS if scope["path"].startswith(DOCS_PATHS) else _STRICT

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                present = {name.lower() for name, _ in message.get("headers", [])}
                message["headers"] = list(message.get("headers", [])) + [
                    (name, value) for name, value in extra if name not in present
                ]
            await send(message)

        await self.app(scope, receive, send_with_headers)
