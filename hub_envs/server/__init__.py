"""A loopback server speaking the Hugging Face Hub HTTP protocol.

The unmodified ``huggingface_hub`` client creates repos, commits, tags, lists and downloads
against it: point ``HF_ENDPOINT`` at it. It is the default hub of the demo, the fixture of the
tests (see :mod:`hub_envs.testing`), and a real hub for air-gapped labs. Repos live on disk under
``root`` (see :mod:`hub_envs.server.storage`); a restarted server serves the same repos. Run one
server process per root.

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

    With ``--token=T``, writes (and reads of private repos) need ``HF_TOKEN=T`` on the client.

    A browser pointed at ``http://127.0.0.1:8000/`` gets the web pages (:mod:`hub_envs.server.pages`):
    the repos, each env's card, files and pinned load line.
"""

from __future__ import annotations

import logging
import os
import socket
import sys

from hub_envs.server.app import create_app

__all__ = ["create_app", "run"]


def run(
    root: str | os.PathLike,
    host: str = "127.0.0.1",
    port: int = 8000,
    token: str | None = None,
    max_body_mb: float | None = None,
    max_line_mb: float | None = None,
    max_lfs_mb: float | None = None,
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
        max_line_mb: largest line of a commit body in MiB (default 1024, or env
            ``HUB_ENVS_SERVER_MAX_LINE_MB``); a line carries one file in base64 (4/3 of its size) and
            is held in memory while it is stored. Larger: 413.
        max_lfs_mb: largest file uploaded through Git LFS, in MiB (default 51200, the Hub's 50 GB, or env
            ``HUB_ENVS_SERVER_MAX_LFS_MB``); LFS files are streamed to disk, never held in memory.
    """
    import uvicorn

    from hub_envs.server.storage import StoreError

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
    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off")
    uvicorn.Server(config).run(sockets=[sock])
