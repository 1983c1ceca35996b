"""The one token guard of every twin page (the twin's and the hall's): HTTP and WebSocket.

A token, once set, is asked of every request: ``Authorization: Bearer TOKEN``, ``?token=TOKEN``
or the ``drafttwin_token`` cookie that a ``?token=`` request sets (so that a page opened with
the token in its address loads its scripts and opens its WebSocket without it). Compared in
constant time. No token: open (the CLI allows that on 127.0.0.1 only).
"""

from __future__ import annotations

import hmac
import time
from collections import OrderedDict
from typing import Any

from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import Response
from starlette.middleware.base import BaseHTTPMiddleware

COOKIE = "drafttwin_token"
FAILED_BURST = 10
"""Wrong tokens a client may send at once; then one more per :data:`FAILED_REFILL_S` (429
meanwhile, before the token is compared: a guess is not even looked at)."""
FAILED_REFILL_S = 6.0
FAILED_HOSTS = 1024
"""Clients whose failures are remembered (the oldest forgotten first)."""


class FailedTokens:
    """A token bucket of wrong tokens per client address."""

    def __init__(self) -> None:
        self.hosts: OrderedDict[str, tuple[float, float]] = OrderedDict()  # tokens, when

    def _tokens(self, host: str, now: float) -> float:
        tokens, then = self.hosts.get(host, (float(FAILED_BURST), now))
        return min(float(FAILED_BURST), tokens + (now - then) / FAILED_REFILL_S)

    def locked(self, host: str) -> bool:
        return host in self.hosts and self._tokens(host, time.monotonic()) < 1.0

    def failed(self, host: str) -> None:
        now = time.monotonic()
        self.hosts[host] = (self._tokens(host, now) - 1.0, now)
        self.hosts.move_to_end(host)
        while len(self.hosts) > FAILED_HOSTS:
            self.hosts.popitem(last=False)


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

    failures = FailedTokens()

    class TokenGuard(BaseHTTPMiddleware):
        async def dispatch(self, request: Request, call_next: Any) -> Any:
            host = request.client.host if request.client is not None else ""
            if token is not None and failures.locked(host):
                return Response("too many wrong tokens: try again later", status_code=429,
                                headers={"Retry-After": str(int(FAILED_REFILL_S))})  # fmt: skip
            given = given_token(request.headers, request.query_params, request.cookies)
            if not admits(token, given):
                failures.failed(host)
                return Response("token required", status_code=401)
            response = await call_next(request)
            if token is not None and request.query_params.get("token"):
                response.set_cookie(COOKIE, token, httponly=True, samesite="strict")
            return response

    app.add_middleware(TokenGuard)


def ws_admits(token: str | None, ws: WebSocket) -> bool:
    """Whether a WebSocket may open (the HTTP middleware does not see WebSockets)."""
    return admits(token, given_token(ws.headers, ws.query_params, ws.cookies))


__all__ = ["COOKIE", "FailedTokens", "admits", "given_token", "guard", "ws_admits"]
