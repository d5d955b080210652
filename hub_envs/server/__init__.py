"""A loopback server speaking the Hugging Face Hub HTTP protocol (``hub-envs serve``): the unmodified
``huggingface_hub`` client creates repos, commits, tags, lists and downloads against it, and a browser gets
its web pages. How it works and what it bounds: ``docs/server.md``.

Example:
    Start it (blocking)::

        $ hub-envs serve --root=./hub-data --port=8000

    then, in another shell::

        $ HF_ENDPOINT=http://127.0.0.1:8000 python -c "
        from huggingface_hub import HfApi
        api = HfApi()
        api.create_repo('alice/pendulum', exist_ok=True)
        api.upload_file(path_or_fileobj=b'hello', path_in_repo='hello.txt', repo_id='alice/pendulum')
        print(api.list_repo_files('alice/pendulum'))"
        ['.gitattributes', 'hello.txt']
"""

from __future__ import annotations

import logging
import os
import socket
import sys

from hub_envs.server.app import create_app
from hub_envs.server.storage import StoreError

__all__ = ["create_app", "run"]


#: A connection must send a whole request head (request line and headers) within this many seconds of
#: connecting, or of its first byte after an answer: otherwise the server answers 408 and closes it.
DEFAULT_HEADER_TIMEOUT = 20.0
#: An idle keep-alive connection (between requests) is closed after this many seconds (uvicorn's default).
KEEP_ALIVE_TIMEOUT = 5
#: At most this many connections (idle keep-alive ones included) and requests in flight; past it, 503.
DEFAULT_MAX_CONNECTIONS = 1000


def run(
    root: str | os.PathLike,
    host: str = "127.0.0.1",
    port: int = 8000,
    token: str | None = None,
    max_body_mb: float | None = None,
    max_line_mb: float | None = None,
    max_lfs_mb: float | None = None,
    header_timeout: float | None = None,
    max_connections: int | None = None,
) -> None:
    """Serve the repos under ``root`` on ``http://host:port`` until interrupted (SIGINT/SIGTERM).

    ``port=0`` picks a free port. Once listening, one line goes to stderr::

        hub-envs server: serving /abs/root at http://127.0.0.1:8000 (writes open to anyone)

    Access logs are off; errors are logged to stderr.

    Args:
        root: the store folder (created if missing). One server process per root.
        host: interface to bind; the default serves this machine only.
        port: TCP port; 0 picks a free one (read it from the line above).
        token: if set, writes and reads of private repos need ``Authorization: Bearer <token>``
            (clients: ``HF_TOKEN=<token>``).
        max_body_mb: largest request body in MiB (default 2048, or env ``HUB_ENVS_SERVER_MAX_BODY_MB``);
            a commit carries all its files in its body. Larger: 413.
        max_line_mb: largest line of a commit body in MiB (default 16, or env
            ``HUB_ENVS_SERVER_MAX_LINE_MB``); a line carries one inline file in base64 (4/3 of its size)
            and is held in memory while it is stored. huggingface_hub sends files over 10 MiB through
            Git LFS, so its lines stay under 14 MiB. Larger: 413.
        max_lfs_mb: largest file uploaded through Git LFS, in MiB (default 51200, the Hub's 50 GB, or env
            ``HUB_ENVS_SERVER_MAX_LFS_MB``); LFS files are streamed to disk, never held in memory.
        header_timeout: seconds a connection has to send a whole request head, from connecting (or from its
            first byte after an answer) (default 20, or env ``HUB_ENVS_SERVER_HEADER_TIMEOUT``); then 408 and
            the connection is closed, so half-open connections do not pile up.
        max_connections: most connections open at once, idle keep-alive ones included, and requests in flight
            (default 1000, or env ``HUB_ENVS_SERVER_MAX_CONNECTIONS``); past it, requests get 503.

    Raises:
        SystemExit: a setting is invalid (e.g. accounts in ``HUB_ENVS_SERVER_USERS`` without ``token``), or the
            port cannot be bound; the message says what to change.
    """
    import uvicorn

    try:
        header_timeout = _setting(header_timeout, "HUB_ENVS_SERVER_HEADER_TIMEOUT", DEFAULT_HEADER_TIMEOUT, float)
        max_connections = _setting(max_connections, "HUB_ENVS_SERVER_MAX_CONNECTIONS", DEFAULT_MAX_CONNECTIONS, int)
    except ValueError as err:
        raise SystemExit(f"hub-envs serve: {err}") from None

    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    logging.getLogger("hub_envs.server.lfs").setLevel(logging.INFO)  # one line per stored LFS object
    try:
        app = create_app(root, token=token, max_body_mb=max_body_mb, max_line_mb=max_line_mb, max_lfs_mb=max_lfs_mb)
    except (StoreError, ValueError) as err:
        raise SystemExit(f"hub-envs serve: {err}") from None
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # IPPROTO_TCP explicitly: asyncio sets TCP_NODELAY on accepted sockets only if proto says TCP,
    # and without it Nagle + delayed ACKs add ~40 ms to every keep-alive request.
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as err:
        sock.close()
        raise SystemExit(
            f"hub-envs serve: cannot listen on {host}:{port} ({err.strerror}). "
            "Pass another --port, or --port=0 to pick a free one."
        ) from None
    sock.listen(2048)
    sock.set_inheritable(True)
    bound_port = sock.getsockname()[1]
    shown_host = f"[{host}]" if family == socket.AF_INET6 else host
    access = "writes need the token" if token else "writes open to anyone"
    print(
        f"hub-envs server: serving {app.state.hub.store.root} at http://{shown_host}:{bound_port} ({access}); "
        f"clients: HF_ENDPOINT=http://{shown_host}:{bound_port} HF_HUB_DISABLE_XET=1 (large files go through Git LFS)",
        file=sys.stderr,
        flush=True,
    )
    config = uvicorn.Config(
        app,
        log_level="warning",
        access_log=False,
        lifespan="off",
        http=_h11_with_header_timeout(header_timeout),  # h11 (bounded request heads: 16 KiB), with a deadline for them
        timeout_keep_alive=KEEP_ALIVE_TIMEOUT,
        limit_concurrency=max_connections,
    )
    uvicorn.Server(config).run(sockets=[sock])


def _setting(value, env: str, default, kind: type):
    """``value``, else the environment variable ``env``, else ``default``: a positive ``kind`` (ValueError if not)."""
    if value is None:
        raw = os.environ.get(env, "").strip()
        try:
            value = kind(raw) if raw else default
        except ValueError:
            raise ValueError(f"{env}={raw!r}: expected a positive number.") from None
    if not value > 0 or value != value or value == float("inf"):
        raise ValueError(f"{env.removeprefix('HUB_ENVS_SERVER_').lower()} must be a positive number, got {value}.")
    return kind(value)


def _h11_with_header_timeout(timeout: float) -> type:
    """uvicorn's h11 protocol with a deadline for each request head.

    uvicorn closes an idle keep-alive connection only once a request was answered on it; a connection that
    connects and sends nothing, or part of a request head a byte at a time, it keeps forever. This one answers
    408 and closes a connection whose request head is not complete ``timeout`` seconds after it connected, or
    after the first byte that followed an answer (more bytes do not extend it). The body is not under this
    deadline (an upload may take long); the request head is at most 16 KiB (h11's default, then 400).
    """
    import h11
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class HeaderTimeoutH11Protocol(H11Protocol):
        _head_timer = None

        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            self._arm_head_timer()

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            if self.conn.their_state is h11.IDLE:  # the next request's head has begun, not ended
                self._arm_head_timer()
            else:
                self._cancel_head_timer()

        def connection_lost(self, exc) -> None:
            self._cancel_head_timer()
            super().connection_lost(exc)

        def _arm_head_timer(self) -> None:
            if self._head_timer is None and not self.transport.is_closing():
                self._head_timer = self.loop.call_later(timeout, self._head_timed_out)

        def _cancel_head_timer(self) -> None:
            if self._head_timer is not None:
                self._head_timer.cancel()
                self._head_timer = None

        def _head_timed_out(self) -> None:
            self._head_timer = None
            if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
                # raw: h11 cannot answer a request it has not received
                self.transport.write(b"HTTP/1.1 408 Request Timeout\r\nconnection: close\r\ncontent-length: 0\r\n\r\n")
                self.transport.close()

    return HeaderTimeoutH11Protocol
