"""HTTP helpers of the loopback Hub server: the parsed request (:class:`Ctx`), errors answered as the Hub
answers them (:class:`HTTPError`), JSON answers, capped request bodies, paging and ``Range`` headers.

No routes and no store here: :mod:`hub_envs.server.app` and the modules below it build on these.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlencode

import anyio
import anyio.to_thread
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import Response

MiB = 1024 * 1024
#: The plural path segment of each repo type (``/api/datasets/...``, ``/datasets/...``).
PLURAL = {"models": "model", "datasets": "dataset", "spaces": "space"}
#: What a repo's URL starts with, per repo type (models have no prefix).
URL_PREFIX = {"model": "", "dataset": "datasets/", "space": "spaces/"}
#: The cap of JSON request bodies (preupload, paths-info, validate-yaml...), unless the body cap is lower.
MAX_JSON_BODY = 32 * MiB
BODY_SETTING = "--max_body_mb / HUB_ENVS_SERVER_MAX_BODY_MB"
_RANGE_RE = re.compile(r"\s*bytes=(\d*)-(\d*)\s*")
_RANGE_MAX_DIGITS = 18  # more digits than any file size: read as "beyond the end", never int()-ed


class HTTPError(Exception):
    """An error answered as-is: status, message, and the Hub's ``X-Error-Code`` when it has one.

    Args:
        status: the HTTP status.
        message: what went wrong and what to do; sent as ``X-Error-Message`` and ``{"error": message}``.
        code: the Hub's error code (``RepoNotFound``, ``RevisionNotFound``, ``EntryNotFound``...), which
            huggingface_hub turns into its typed errors.
        headers: more response headers.
        extra: more fields of the JSON body (e.g. ``filesWithConflicts``).
    """

    def __init__(
        self, status: int, message: str, code: str | None = None, headers: dict | None = None, extra: dict | None = None
    ):
        super().__init__(message)
        self.status = status
        self.message = message
        self.code = code
        self.headers = headers or {}
        self.extra = extra or {}


@dataclass
class Ctx:
    """One request, parsed: decoded path segments, query, body, who is calling and how much body it may send."""

    request: Request
    method: str
    segs: list[str]
    user: str | None  # None: anonymous (only when the server has a token and none was sent)
    body: bytes = b""
    body_limit: int = MAX_JSON_BODY  # what read_body accepts...
    body_limit_name: str = "the limit of JSON request bodies on this server"  # ... and what the 413 calls it

    @property
    def authenticated(self) -> bool:
        return self.user is not None

    @property
    def base_url(self) -> str:
        return str(self.request.base_url).rstrip("/")

    def query(self, name: str, default: str | None = None) -> str | None:
        """A query parameter.

        Args:
            name: its name.
            default: what to return when the query does not have it.
        """
        return self.request.query_params.get(name, default)

    def flag(self, name: str) -> bool:
        """Whether a query parameter is set to ``1``, ``true`` or ``yes``.

        Args:
            name: its name.
        """
        return (self.query(name) or "").lower() in ("1", "true", "yes")


def json_response(data: Any, status: int = 200, headers: dict | None = None) -> Response:
    """``data`` as a JSON answer.

    Args:
        data: JSON-ready data.
        status: the HTTP status.
        headers: more response headers.
    """
    return Response(json.dumps(data), status_code=status, headers=headers, media_type="application/json")


def error_response(err: HTTPError) -> Response:
    """The Hub's error answer: ``X-Error-Code``/``X-Error-Message`` headers and an ``{"error": ...}`` body.

    Args:
        err: the error.
    """
    headers = {"X-Error-Message": re.sub(r"[^\x20-\x7e]", "?", err.message)[:1000], **err.headers}
    if err.code:
        headers["X-Error-Code"] = err.code
    return json_response({"error": err.message, **err.extra}, status=err.status, headers=headers)


def repo_url(base_url: str, repo_type: str, repo_id: str) -> str:
    """A repo's URL on this server, as the Hub spells it (``{base}/datasets/{id}`` for a dataset).

    Args:
        base_url: the server's URL as the request reached it.
        repo_type: ``model``, ``dataset`` or ``space``.
        repo_id: ``namespace/name``.
    """
    return f"{base_url}/{URL_PREFIX[repo_type]}{repo_id}"


# --- request bodies ---------------------------------------------------------------------------------


def limit_bytes(value: float | None, env: str, default: float, name: str) -> int:
    """A size limit given in MiB, in bytes.

    Args:
        value: the limit in MiB, or None to read ``env``.
        env: the environment variable read when ``value`` is None.
        default: the limit in MiB when neither is set.
        name: the setting's name, for the error message.

    Returns:
        The limit in bytes (at least 1).

    Raises:
        ValueError: the limit is not a positive number.
    """
    if value is None:
        raw = os.environ.get(env, "").strip()
        try:
            value = float(raw) if raw else default
        except ValueError:
            raise ValueError(f"{env}={raw!r}: expected a number of MiB, such as 512.") from None
    value = float(value)
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number of MiB, got {value}.")
    return max(1, int(value * MiB))


def format_limit(n: int) -> str:
    """A byte limit as error messages give it: ``16 MiB``, ``512 bytes``.

    Args:
        n: a number of bytes.
    """
    return f"{n / MiB:g} MiB" if n >= MiB else f"{n} bytes"


def too_large(limit: int, what: str) -> HTTPError:
    """The 413 of a body over ``limit`` bytes; ``what`` names the limit and how to change it.

    Args:
        limit: the limit in bytes.
        what: the limit's name and how to change it.
    """
    return HTTPError(413, f"Request too large: over {format_limit(limit)}, {what}.")


def check_declared_length(ctx: Ctx, limit: int, what: str) -> None:
    """413 at once if ``Content-Length`` announces more than ``limit``: nothing is read.

    Args:
        ctx: the request.
        limit: the limit in bytes.
        what: the limit's name and how to change it.

    Raises:
        HTTPError: 413.
    """
    declared = ctx.request.headers.get("content-length", "").strip()
    if declared.isdigit() and (len(declared) > 18 or int(declared) > limit):
        raise too_large(limit, what)


async def read_body(ctx: Ctx) -> bytes:
    """The request body, read up to ``ctx.body_limit`` bytes (413 past it, as soon as it is passed).

    Args:
        ctx: the request.

    Raises:
        HTTPError: 413 naming ``ctx.body_limit_name``.
        ClientDisconnect: the client went away before sending it all.
    """
    limit, what = ctx.body_limit, ctx.body_limit_name
    check_declared_length(ctx, limit, what)
    body = bytearray()
    async for chunk in ctx.request.stream():
        body += chunk
        if len(body) > limit:
            raise too_large(limit, what)
    return bytes(body)


def body_json(ctx: Ctx) -> dict:
    """``ctx.body`` as a JSON object (``{}`` when empty); 400 if it is not one.

    Args:
        ctx: the request, its body read (:func:`read_body`).

    Raises:
        HTTPError: 400, saying what is wrong with the body.
    """
    raw = ctx.body
    if not raw.strip():
        return {}
    try:
        data = json.loads(raw)
    except ValueError as err:
        raise HTTPError(400, f"Request body is not valid JSON: {err}.") from None
    except RecursionError:
        raise HTTPError(400, "Request body is not valid JSON: nested too deeply.") from None
    if not isinstance(data, dict):
        raise HTTPError(400, "Request body must be a JSON object.")
    return data


def require_user(ctx: Ctx) -> str:
    """The calling account; 401 for an anonymous caller (a server with a token, and none sent).

    Args:
        ctx: the request.

    Raises:
        HTTPError: 401, saying to set ``HF_TOKEN``.
    """
    if ctx.user is None:
        raise HTTPError(
            401,
            "Authentication required: this hub-envs server was started with --token, and write requests "
            "must send it (`Authorization: Bearer <token>`). Set HF_TOKEN to that token, or pass token=...",
        )
    return ctx.user


def only(ctx: Ctx, method: str) -> None:
    """405 unless the request's method is ``method``.

    Args:
        ctx: the request.
        method: the one method allowed.

    Raises:
        HTTPError: 405 with an ``Allow`` header.
    """
    if ctx.method != method:
        raise HTTPError(405, f"Method {ctx.method} not allowed here (allowed: {method}).", headers={"Allow": method})


async def call(
    ctx: Ctx,
    handlers: dict[str, Callable[[Ctx], Response]],
    body: bool = False,
    write: bool = False,
    threads: anyio.CapacityLimiter | None = None,
) -> Response:
    """Run the handler of the request's method in a worker thread.

    Args:
        ctx: the request.
        handlers: method (``"GET"``...) -> handler; HEAD runs GET's handler when it has none of its own.
        body: read the (JSON) request body into ``ctx.body`` first, capped at ``ctx.body_limit``.
        write: the caller must be authenticated, checked before a byte of the body is read.
        threads: the threads to run it in (default: the API's).

    Returns:
        The handler's answer.

    Raises:
        HTTPError: 405 for a method without a handler, 401 or 413 as above, or the handler's own.
    """
    handler = handlers.get(ctx.method)
    if handler is None and ctx.method == "HEAD":
        handler = handlers.get("GET")  # HEAD is GET without the body (uvicorn drops it)
    if handler is None:
        allowed = ", ".join(sorted(handlers))
        raise HTTPError(405, f"Method {ctx.method} not allowed here (allowed: {allowed}).", headers={"Allow": allowed})
    if write:
        require_user(ctx)  # before reading a single byte of the body
    if body:
        ctx.body = await read_body(ctx)
    if threads is not None:
        return await anyio.to_thread.run_sync(handler, ctx, limiter=threads)
    return await run_in_threadpool(handler, ctx)


# --- lists and ranges -------------------------------------------------------------------------------


def paginate(ctx: Ctx, items: list, size: int, param: str) -> tuple[list, dict]:
    """One page of ``items`` and its headers: ``Link: <next page>; rel="next"`` when there is more.

    Args:
        ctx: the request; its query holds ``param`` and ``limit``.
        items: the whole list.
        size: the page size (``limit`` may ask for less).
        param: ``"cursor"`` (an offset, as the tree) or ``"p"`` (a page number, as the commits).

    Returns:
        ``(page, headers)``.

    Raises:
        HTTPError: 400 for a query value that is not a number.
    """
    try:
        start = int(ctx.query(param) or 0)
        limit = int(ctx.query("limit") or size)
    except ValueError:
        raise HTTPError(400, f"Invalid '{param}' or 'limit' query parameter.") from None
    start, limit = max(start, 0), max(1, min(limit, size))
    if param == "p":
        start *= limit
    page = items[start : start + limit]
    headers = {}
    if start + limit < len(items):
        nxt = start + limit if param != "p" else (start + limit) // limit
        # from the raw path: a decoded one would turn "feature%2Fx" into two segments
        raw_path = (ctx.request.scope.get("raw_path") or ctx.request.url.path.encode()).decode("latin-1")
        query = [(k, v) for k, v in ctx.request.query_params.multi_items() if k != param] + [(param, str(nxt))]
        headers["Link"] = f'<{ctx.base_url}{raw_path}?{urlencode(query)}>; rel="next"'
    return page, headers


def _range_int(digits: str) -> int:
    return int(digits) if len(digits) <= _RANGE_MAX_DIGITS else 10**_RANGE_MAX_DIGITS


def parse_range(header: str, size: int) -> tuple[int, int] | str | None:
    """A ``Range`` header for a file of ``size`` bytes.

    Args:
        header: the ``Range`` header's value.
        size: the file's size in bytes.

    Returns:
        ``(start, end)`` inclusive for a single ``bytes=`` range, ``"unsatisfiable"``, or None to ignore it
        (RFC 9110 14.2: then the whole file is sent with 200).
    """
    match = _RANGE_RE.fullmatch(header)
    if not match or (not match.group(1) and not match.group(2)):
        return None  # malformed or multi-range: ignored, the whole file is sent (RFC 9110 allows it)
    first = _range_int(match.group(1)) if match.group(1) else None
    last = _range_int(match.group(2)) if match.group(2) else None
    if first is not None:
        if last is not None and last < first:
            return None  # invalid range-spec: ignored
        if first >= size:
            return "unsatisfiable"
        return first, size - 1 if last is None else min(last, size - 1)
    if last == 0:
        return "unsatisfiable"
    if size == 0:
        return None  # a suffix of an empty file is the empty file itself: 200, no Content-Range to express
    return max(size - last, 0), size - 1
