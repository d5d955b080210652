"""Fault injection for the loopback Hub server: make it fail on purpose, to test the clients. Off unless
``HUB_ENVS_SERVER_FAULTS`` (inline JSON, or a JSON file re-read when it changes) holds rules; each rule
answers a status, drops a response mid-body or ends the server mid-upload. The rules: ``docs/server.md#fault-injection``.

Example:
    >>> import json, os, tempfile
    >>> from starlette.testclient import TestClient
    >>> from hub_envs.server import create_app
    >>> os.environ["HUB_ENVS_SERVER_FAULTS"] = json.dumps({"match": "GET /api/whoami", "times": 1})
    >>> client = TestClient(create_app(tempfile.mkdtemp()))
    >>> [client.get("/api/whoami-v2").status_code for _ in range(2)]
    [500, 200]
    >>> del os.environ["HUB_ENVS_SERVER_FAULTS"]
"""

from __future__ import annotations

import json
import logging
import os
import re
from pathlib import Path
from typing import Any

ENV_VAR = "HUB_ENVS_SERVER_FAULTS"
ACTIONS = ("status", "drop", "exit")

logger = logging.getLogger("hub_envs.server.faults")


class InjectedFault(ConnectionAbortedError):
    """Raised inside the server to abort a response on purpose (a ``drop`` rule)."""


class _Rules:
    """The rules and their counters; re-read from the file when it changes."""

    def __init__(self, value: str):
        self.value = value.strip()
        self.path = None if self.value[:1] in "[{" else Path(self.value)
        self.stamp: tuple | None = None
        self.rules: list[dict[str, Any]] = []
        if self.path is None:
            self.rules = self._parse(self.value)

    @staticmethod
    def _parse(text: str) -> list[dict[str, Any]]:
        data = json.loads(text) if text.strip() else []
        rules = data if isinstance(data, list) else [data]
        out = []
        for rule in rules:
            action = rule.get("action", "status")
            if action not in ACTIONS:
                raise ValueError(f"{ENV_VAR}: unknown action {action!r} (expected one of {ACTIONS}).")
            out.append(
                {
                    "match": re.compile(rule.get("match", "")),
                    "action": action,
                    "times": int(rule.get("times", 1)),
                    "skip": int(rule.get("skip", 0)),
                    "status": int(rule.get("status", 500)),
                    "after_bytes": int(rule.get("after_bytes", 0)),
                }
            )
        return out

    def take(self, request_line: str) -> dict[str, Any] | None:
        if self.path is not None:
            try:
                st = self.path.stat()
                stamp = (st.st_mtime_ns, st.st_size)
            except FileNotFoundError:
                stamp = None
            if stamp != self.stamp:
                self.stamp = stamp
                self.rules = self._parse(self.path.read_text()) if stamp is not None else []
        for rule in self.rules:
            if not rule["match"].search(request_line):
                continue
            if rule["skip"] > 0:
                rule["skip"] -= 1
                return None
            if rule["times"] == 0:
                continue
            if rule["times"] > 0:
                rule["times"] -= 1
            return rule
        return None


class FaultMiddleware:
    """ASGI middleware applying the rules of ``HUB_ENVS_SERVER_FAULTS`` (``docs/server.md#fault-injection``)."""

    def __init__(self, app, spec: str):
        self.app = app
        self.rules = _Rules(spec)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        raw = scope.get("raw_path") or scope["path"].encode()
        rule = self.rules.take(f"{scope['method']} {raw.decode('latin-1')}")
        if rule is None:
            return await self.app(scope, receive, send)
        logger.warning("injected fault %s on %s %s", rule["action"], scope["method"], scope["path"])
        if rule["action"] == "status":
            while (await receive()).get("more_body"):  # drain the request body
                pass
            body = json.dumps({"error": f"Injected fault ({ENV_VAR})"}).encode()
            await send(
                {
                    "type": "http.response.start",
                    "status": rule["status"],
                    "headers": [
                        (b"content-type", b"application/json"),
                        (b"content-length", str(len(body)).encode()),
                        (b"x-error-message", b"Injected fault"),
                    ],
                }
            )
            await send({"type": "http.response.body", "body": body})
            return
        if rule["action"] == "exit":
            received = 0
            while received < rule["after_bytes"]:
                message = await receive()
                received += len(message.get("body", b""))
                if not message.get("more_body"):
                    break
            os._exit(70)
        budget = rule["after_bytes"]

        async def send_then_drop(message):
            nonlocal budget
            if message["type"] == "http.response.body":
                body = message.get("body", b"")
                if len(body) >= budget:
                    await send({"type": "http.response.body", "body": body[:budget], "more_body": True})
                    raise InjectedFault(f"{ENV_VAR}: connection dropped on purpose")
                budget -= len(body)
            await send(message)

        await self.app(scope, receive, send_then_drop)


def install_faults(app) -> None:
    """Add :class:`FaultMiddleware` to a Starlette ``app`` if ``HUB_ENVS_SERVER_FAULTS`` is set.

    Args:
        app: the Starlette app. Rules that are not valid (``docs/server.md#fault-injection``) raise ValueError
            when the app builds its middleware, at its first request.
    """
    spec = os.environ.get(ENV_VAR)
    if spec:
        app.add_middleware(FaultMiddleware, spec=spec)
