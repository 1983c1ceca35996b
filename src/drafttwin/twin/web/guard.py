"""The one token guard of every twin page (the twin's and the hall's): HTTP and WebSocket.

A token, once set, is asked of every request: ``Authorization: Bearer TOKEN``, ``?token=TOKEN``
or the ``drafttwin_token`` cookie that a ``?token=`` request sets (so that a page opened with
the token in its address loads its scripts and opens its WebSocket without it). Compared in
constant time. No token: open (the CLI allows that on 127.0.0.1 only).
"""

from __future__ import annotations

import hmac
from typing import Any

from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import Response
from starlette.middleware.base import BaseHTTPMiddleware

COOKIE = "drafttwin_token"


def admits(token: str | None, given: str | None) -> bool:
    """Whether ``given`` passes ``token`` (none: everything passes)."""
    return token is None or (given is not None and hmac.compare_digest(token, given))


def given_token(headers: Any, query: Any, cookies: Any) -> str | None:
    """The token a request brings: its bearer header, else ``?token=``, else the cookie."""
    auth = headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return str(auth[7:].strip())
    found: str | None = query.get("token") or cookies.get(COOKIE)
    return found


def guard(app: FastAPI, token: str | None) -> None:
    """Every HTTP route of ``app`` checks ``token`` (none: open); ``?token=`` sets the cookie."""

    class TokenGuard(BaseHTTPMiddleware):
        async def dispatch(self, request: Request, call_next: Any) -> Any:
            given = given_token(request.headers, request.query_params, request.cookies)
            if not admits(token, given):
                return Response("token required", status_code=401)
            response = await call_next(request)
            if token is not None and request.query_params.get("token"):
                response.set_cookie(COOKIE, token, httponly=True, samesite="strict")
            return response

    app.add_middleware(TokenGuard)


def ws_admits(token: str | None, ws: WebSocket) -> bool:
    """Whether a WebSocket may open (the HTTP middleware does not see WebSockets)."""
    return admits(token, given_token(ws.headers, ws.query_params, ws.cookies))


__all__ = ["COOKIE", "admits", "given_token", "guard", "ws_admits"]
