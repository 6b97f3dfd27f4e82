"""Request size limits and the planning budget of one request.

``BodySizeLimit`` is a pure ASGI middleware: a request whose ``Content-Length`` exceeds the
limit is answered 413 before its body is read, and a body sent without a length (chunked) is
read up to the limit and answered 413 as soon as it goes past it; the application then
receives the body already read.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from orange_plan.service.worker import Budget


@dataclass(frozen=True)
class Limits:
    """What one request may carry.

    Attributes
    ----------
    max_body_bytes : any request body [bytes]
    max_samples : telemetry samples in one batch
    max_scenario_bytes : inline scenario TOML [bytes]
    max_geometry_vertices : vertices in one map update
    plan_memory_bytes : memory a plan (a new mission's first tour, a replan) may take in its
        planning worker, beyond what the worker starts with [bytes]
    plan_seconds : time a plan may take before its worker is stopped [s]
    planners : planning workers at once (each within the two budgets above)

    The sizes a mission may ask for (roadmap vertices, the sensor radius against its map)
    are limited by ``orange_plan.limits``, the same limits as on the command line.
    """

    max_body_bytes: int = 8 * 1024 * 1024
    max_samples: int = 50_000
    max_scenario_bytes: int = 64 * 1024
    max_geometry_vertices: int = 10_000
    plan_memory_bytes: int = 4 * 2**30
    plan_seconds: float = 300.0
    planners: int = 2

    def budget(self) -> Budget:
        """What one planning request may use."""
        return Budget(self.plan_memory_bytes, self.plan_seconds, self.planners)


class BodySizeLimit:
    """Answer 413 to any request body larger than ``max_bytes``."""

    def __init__(self, app, max_bytes: int):
        self.app = app
        self.max_bytes = int(max_bytes)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = None
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                length = value
        if length is not None:
            if not length.isdigit():
                await _answer(send, 400, "Content-Length is not a number")
                return
            if int(length) > self.max_bytes:
                await _answer(send, 413, self._too_large())
                return
            await self.app(scope, receive, send)  # the server stops reading at the length
            return
        body = bytearray()
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            body += message.get("body", b"")
            if len(body) > self.max_bytes:
                await _answer(send, 413, self._too_large())
                return
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay():
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": bytes(body), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)

    def _too_large(self) -> str:
        return f"request body larger than {self.max_bytes} bytes"


async def _answer(send, status: int, detail: str) -> None:
    payload = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(payload)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": payload})
