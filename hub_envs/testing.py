"""Test helpers: a loopback Hub server in a subprocess (:class:`HubServer`), and the clients pointed at it
(:func:`hub_environment`).

Example:
    >>> import tempfile
    >>> from pathlib import Path
    >>> from huggingface_hub import HfApi, hf_hub_download
    >>> from hub_envs.testing import HubServer, hub_environment
    >>> tmp = Path(tempfile.mkdtemp())
    >>> with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "hf_home"):
    ...     api = HfApi()
    ...     _ = api.create_repo("alice/pendulum")
    ...     _ = api.upload_file(path_or_fileobj=b"hi", path_in_repo="a.txt", repo_id="alice/pendulum")
    ...     Path(hf_hub_download("alice/pendulum", "a.txt")).read_bytes()
    b'hi'
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import huggingface_hub

from hub_envs._compat import point_clients_at, reset_http_sessions
from hub_envs.repo.format import DATASET_DIR, MANIFEST_FILE, content_digest

__all__ = ["HubServer", "HubServerError", "hub_environment"]

_LISTENING = re.compile(r"hub-envs server: serving .* at (http://\S+?:(\d+)) ")
_LIVE_SERVERS: weakref.WeakSet[HubServer] = weakref.WeakSet()


class HubServerError(RuntimeError):
    """The loopback server did not start, or died; the message ends with its stderr."""


class HubServer:
    """A ``hub-envs serve`` subprocess on ``127.0.0.1``, for tests and demos.

    Args:
        root: the store folder (created if missing).
        token: start the server with ``--token`` (writes and private reads need it).
        port: a fixed port; default: a free one, picked by the server (``--port=0``) and kept across
            :meth:`restart`.
        page_size: small page size for the tree and commits lists (env ``HUB_ENVS_SERVER_PAGE_SIZE``),
            to exercise paging in tests.
        startup_timeout: seconds to wait for the first successful response.
        env: extra environment variables for the server process.

    The server starts in the constructor. Use it as a context manager, or call :meth:`stop`;
    any still running at interpreter exit are stopped.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        *,
        token: str | None = None,
        port: int | None = None,
        page_size: int | None = None,
        startup_timeout: float = 30.0,
        env: dict[str, str] | None = None,
    ):
        self.root = Path(root).resolve()
        self.token = token
        self.port = port
        self.page_size = page_size
        self.startup_timeout = startup_timeout
        self.extra_env = dict(env or {})
        self.process: subprocess.Popen | None = None
        self._log_path: Path | None = None
        self._log_offset = 0
        self._log_file = None
        self.start()

    # -- lifecycle --

    @property
    def endpoint(self) -> str:
        """``http://127.0.0.1:PORT``: what ``HF_ENDPOINT`` should be."""
        if self.port is None:
            raise HubServerError("The server has no port yet: it was never started.")
        return f"http://127.0.0.1:{self.port}"

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def start(self) -> HubServer:
        """Start the server and wait until it answers. No-op if it is running."""
        if self.running:
            return self
        self.root.mkdir(parents=True, exist_ok=True)
        if self._log_path is None:
            fd, log_path = tempfile.mkstemp(prefix="hub-envs-server-", suffix=".log")
            os.close(fd)
            self._log_path = Path(log_path)
        self._log_offset = self._log_path.stat().st_size
        self._log_file = open(self._log_path, "ab")
        cmd = [sys.executable, "-m", "hub_envs.cli", "serve", f"--root={self.root}", f"--port={self.port or 0}"]
        if self.token:
            cmd.append(f"--token={self.token}")
        env = {**os.environ, "PYTHONUNBUFFERED": "1", **self.extra_env}
        if self.page_size is not None:
            env["HUB_ENVS_SERVER_PAGE_SIZE"] = str(self.page_size)
        self.process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self._log_file, stderr=subprocess.STDOUT, env=env)
        _LIVE_SERVERS.add(self)
        try:
            self._wait_until_ready()
        except BaseException:
            self.kill()
            raise
        return self

    def _wait_until_ready(self) -> None:
        deadline = time.monotonic() + self.startup_timeout
        announced = False
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise HubServerError(
                    f"The hub-envs server exited with code {self.process.returncode} before answering.\n"
                    f"--- server output ---\n{self.output()}"
                )
            if not announced:  # the server prints its port once it is listening
                match = _LISTENING.search(self.output()[self._log_offset :])
                if match:
                    self.port, announced = int(match.group(2)), True
            if announced and self._answers():
                return
            time.sleep(0.01)
        raise HubServerError(
            f"The hub-envs server did not answer within {self.startup_timeout:.0f}s (port {self.port}).\n"
            f"--- server output ---\n{self.output()}"
        )

    def _answers(self) -> bool:
        opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # loopback: never via a proxy
        try:
            with opener.open(f"{self.endpoint}/api/whoami-v2", timeout=2):
                return True
        except urllib.error.HTTPError:
            return True  # 401 from a server with a token: it answers
        except (urllib.error.URLError, ConnectionError, OSError):
            return False

    def output(self) -> str:
        """Everything the server printed so far (stdout and stderr)."""
        if self._log_path is None or not self._log_path.exists():
            return ""
        return self._log_path.read_text(errors="replace")

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the server gracefully: SIGTERM, then SIGKILL. Idempotent.

        Args:
            timeout: seconds to wait after SIGTERM.
        """
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._close_log()

    def kill(self) -> None:
        """Kill the server with SIGKILL: no cleanup, as in a crash."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self._close_log()

    def restart(self) -> HubServer:
        """Stop (if running) and start again with the same root, token and port."""
        self.stop()
        return self.start()

    def _close_log(self) -> None:
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None
        _LIVE_SERVERS.discard(self)

    def __enter__(self) -> HubServer:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        self.remove_log()

    def remove_log(self) -> None:
        """Delete the file holding the server's output (kept after :meth:`stop` for post-mortems)."""
        if self._log_path is not None:
            self._log_path.unlink(missing_ok=True)
            self._log_path = None

    def __repr__(self) -> str:
        state = "running" if self.running else "stopped"
        return f"HubServer(root={str(self.root)!r}, endpoint={self.endpoint if self.port else None!r}, {state})"


@atexit.register
def _stop_live_servers() -> None:
    for server in list(_LIVE_SERVERS):
        with contextlib.suppress(Exception):
            server.stop(timeout=3)
            server.remove_log()


# --- client environment -----------------------------------------------------------------------

_UNSET = object()


@contextlib.contextmanager
def hub_environment(
    endpoint: str,
    hf_home: str | os.PathLike,
    token: str | None = None,
    offline: bool = False,
) -> Iterator[None]:
    """Point ``huggingface_hub`` at ``endpoint`` with caches under ``hf_home``, inside a ``with``; everything is restored on
    exit. Not thread-safe: it mutates process-wide state.

    It sets ``HF_ENDPOINT``, ``HF_HOME``, ``HF_HUB_CACHE``, ``HF_ASSETS_CACHE``, ``HF_XET_CACHE``, ``HF_TOKEN`` (or removes it
    when ``token`` is None, so no stored token leaks in), ``HF_HUB_DISABLE_TELEMETRY=1``, ``HF_HUB_DISABLE_XET=1`` (the
    loopback server takes large files through Git LFS), ``HF_HUB_OFFLINE``, ``HF_LEROBOT_HOME``, ``HF_DATASETS_CACHE``,
    ``HUB_ENVS_HOME`` (a folder beside ``hf_home``) and, for a loopback endpoint, ``NO_PROXY``; patches what the clients
    computed at import time (:func:`hub_envs._compat.point_clients_at`); resets the client's HTTP sessions and the
    ``HfFileSystem`` instance cache.

    Args:
        endpoint: the Hub's URL.
        hf_home: the ``HF_HOME`` to use.
        token: the Hub token (None: none at all).
        offline: the clients' offline mode.

    Yields:
        None, inside the block.
    """
    endpoint = endpoint.rstrip("/")
    home = Path(hf_home).resolve()
    home.mkdir(parents=True, exist_ok=True)
    hub_cache, assets_cache = str(home / "hub"), str(home / "assets")
    xet_cache = str(home / "xet")
    env = {
        "HF_ENDPOINT": endpoint,
        "HF_HOME": str(home),
        "HF_HUB_CACHE": hub_cache,
        "HF_ASSETS_CACHE": assets_cache,
        "HF_XET_CACHE": xet_cache,
        "HF_TOKEN": token,
        "HUGGING_FACE_HUB_TOKEN": None,
        "HF_TOKEN_PATH": None,
        "HUGGINGFACE_HUB_CACHE": None,
        "HUGGINGFACE_ASSETS_CACHE": None,
        "HF_HUB_DISABLE_TELEMETRY": "1",
        # the loopback server stores large files through Git LFS, not Xet: huggingface_hub 1.x would
        # upload through Xet whenever hf_xet is installed (see hub_envs.server.lfs)
        "HF_HUB_DISABLE_XET": "1",
        "HF_HUB_OFFLINE": "1" if offline else None,
        "TRANSFORMERS_OFFLINE": None,
        "HF_DATASETS_OFFLINE": None,
        "HF_LEROBOT_HOME": str(home / "lerobot"),
        "HF_DATASETS_CACHE": str(home / "datasets"),
        # hub-envs' own state (trust list, check cache) beside this HF_HOME, as private as it is
        "HUB_ENVS_HOME": str(home.parent / f"{home.name}.hub-envs"),
    }
    host = urllib.parse.urlsplit(endpoint).hostname or ""
    if host in ("127.0.0.1", "localhost", "::1"):  # a proxy (HTTP_PROXY) must not see loopback traffic
        for var in ("NO_PROXY", "no_proxy"):
            current = [h for h in os.environ.get(var, "").split(",") if h]
            env[var] = ",".join(current + [h for h in (host, "localhost", "127.0.0.1") if h not in current])
    saved_env = {k: os.environ.get(k, _UNSET) for k in env}
    patches: list[tuple[object, str, object]] = []  # (module, attribute, old value)

    def patch(module: Any, name: str, value: Any) -> None:
        if module is not None and hasattr(module, name):
            patches.append((module, name, getattr(module, name)))
            setattr(module, name, value)

    try:
        for k, v in env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

        point_clients_at(
            endpoint,
            home,
            offline=offline,
            lerobot_home=Path(env["HF_LEROBOT_HOME"]),
            datasets_cache=Path(env["HF_DATASETS_CACHE"]),
            patch=patch,
        )
        _reset_client_state(huggingface_hub)
        yield
    finally:
        for module, name, old in reversed(patches):
            setattr(module, name, old)
        for k, old in saved_env.items():
            if old is _UNSET:
                os.environ.pop(k, None)
            else:
                os.environ[k] = old  # type: ignore[assignment]
        with contextlib.suppress(Exception):
            _reset_client_state(huggingface_hub)


def _reset_client_state(huggingface_hub) -> None:
    """Drop what the client cached about the previous endpoint: HTTP sessions (their offline
    adapter is chosen at creation) and ``HfFileSystem`` instances (fsspec caches them by arguments)."""
    reset_http_sessions()
    huggingface_hub.HfFileSystem.clear_instance_cache()


def add_random_data_files(folder: Path, count: int, mib_each: int, *, chunk: str = "chunk-001") -> dict[str, str]:
    """Grow the dataset of the env repo in ``folder`` (a published snapshot copied out, or push_env's folder) by random
    files under ``dataset/data/<chunk>/``, listed in its manifest (the files and the content digest updated), as a large
    camera dataset would be. For tests and benchmarks of the Hub at real sizes (the bytes are not parquet: they are
    fetched and verified, not decoded). Publish the folder with :func:`hub_envs.repo.hub_io.publish_folder`.

    Args:
        folder: the env repo's folder.
        count: how many files.
        mib_each: MiB of random bytes each.
        chunk: the data chunk folder.

    Returns:
        ``{path: sha256}`` of the files added.
    """
    manifest = json.loads((folder / MANIFEST_FILE).read_text())
    added = {}
    for i in range(count):
        rel = f"{DATASET_DIR}/data/{chunk}/file-{i:03d}.parquet"
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        with open(folder / rel, "wb") as f:
            for _ in range(mib_each):
                block = os.urandom(1 << 20)
                digest.update(block)
                f.write(block)
        added[rel] = manifest["files"][rel] = digest.hexdigest()
    manifest["content_digest"] = content_digest(manifest["files"])
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2))
    return added
