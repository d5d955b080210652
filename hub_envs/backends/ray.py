"""The Ray backend: episodes sharded by index across Ray tasks, each worker loading the env the way a user does, the
shards consumed in order on the driver (the results byte-identical to the local backend's).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import pickle
import shutil
import socket
import sys
import tempfile
import time
import weakref
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from huggingface_hub import get_token

from hub_envs.backends.base import Backend, EnvSource
from hub_envs.errors import (
    ClusterAuthError,
    ClusterUnreachableError,
    ConfigError,
    EnvCodeError,
    HubEnvsError,
    MissingRequirementsError,
)
from hub_envs.harness.policy import policy_for
from hub_envs.harness.rollout import EpisodeRollout, EpisodeRunner, check_seeds, progress_bar
from hub_envs.repo import hub_io

PIP_LINE = "pip install 'hub-envs[ray]'"
#: Hub client settings a Ray worker gets from the driver (besides ``HF_ENDPOINT``, always sent), when set here: how
#: to reach the Hub. Folders (``HF_HOME``, ``HF_HUB_CACHE``, ``HUB_ENVS_HOME``...) are not sent: the driver's paths
#: need not exist on a node (or may be someone else's there), so each node keeps its own cache and hub-envs state.
HUB_SETTINGS = ("HF_HUB_DISABLE_TELEMETRY", "HF_HUB_DISABLE_XET", "HF_HUB_ETAG_TIMEOUT", "HF_HUB_DOWNLOAD_TIMEOUT")
#: ``0``: do not send the driver's Hub token to the workers (they use their node's own, e.g. ``HF_TOKEN`` set there)
SEND_TOKEN_VAR = "HUB_ENVS_RAY_SEND_TOKEN"
#: Ray's setting (read when ``ray`` is imported) that keeps a loopback address on loopback; see :func:`_check_route`
LOOPBACK_SETTING = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
#: Ray's bound on ``ray.init``'s attempts to reach a cluster's GCS (``ray/_private/node.py`` ``_init_gcs_client``), set
#: for the connection unless set here: Ray's own 20 (each attempt up to about 40 s) wait for a GCS that is restarting,
#: and the preflight has just had the GCS answer
GCS_ATTEMPTS_VAR, GCS_ATTEMPTS = "RAY_gcs_server_port_wait_time_s", 2
#: retries of a shard whose worker process died
MAX_RESTARTS = 3
MAX_SHARD_SIZE = 32


def _ray_missing() -> MissingRequirementsError:
    return MissingRequirementsError(
        f"--backend=ray needs Ray, which is not installed in this Python ({sys.executable}). "
        f"Install the extra: {PIP_LINE} (or use --backend=local)."
    )


def check_ray_installed() -> None:
    """Raise :class:`MissingRequirementsError` (with the pip line) unless Ray can be imported here; cheap (no import),
    so a run asked for on Ray fails before any work rather than after its env was loaded and checked."""
    try:
        found = importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise _ray_missing()


def import_ray():
    """``ray``, or a :class:`MissingRequirementsError` with the pip line."""
    try:
        import ray  # heavy: ray
    except ModuleNotFoundError as exc:
        if exc.name != "ray":
            raise
        raise _ray_missing() from None
    return ray


def _send_token_setting() -> bool:
    value = os.environ.get(SEND_TOKEN_VAR, "1").strip().lower()
    if value not in ("0", "1", "false", "true", "no", "yes"):
        raise ConfigError(f"{SEND_TOKEN_VAR}={value!r}: set 1 (send the driver's Hub token to the Ray workers) or 0 (do not).")
    return value in ("1", "true", "yes")


def _probe(address: str, timeout: float = 5.0) -> None:
    """Raise ClusterUnreachableError unless something listens at ``host:port`` (ray:// too)."""
    if address in ("auto", "local"):
        return
    hostport = address.split("://", 1)[-1]
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit():
        raise ConfigError(f"ray_address={address!r}: write it as host:port (or ray://host:port), e.g. 127.0.0.1:6379.")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            pass
    except OSError as exc:
        raise ClusterUnreachableError(
            f"No Ray cluster answers at {address} ({exc.strerror or exc}). Start one there (ray start --head), "
            "fix --ray_address / RAY_ADDRESS, or leave both unset to start a local Ray for the run."
        ) from None


def _ray_connects_to(address: str) -> str:
    """The ``host:port`` that ``ray.init(address=address)`` connects to from this process.

    Ray replaces a loopback host (``127.0.0.1``, ``localhost``) by this machine's outward address
    (``ray/_private/services.py``: ``canonicalize_bootstrap_address`` -> ``resolve_ip_for_localhost``) unless
    ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` was set when ``ray`` was imported (``ray_constants.ENABLE_RAY_CLUSTER``).
    """
    if "://" in address or address in ("auto", "local"):
        return address
    try:
        from ray._private.services import canonicalize_bootstrap_address  # heavy: ray
    except ImportError:
        return address
    try:
        return canonicalize_bootstrap_address(address) or address
    except Exception:  # noqa: BLE001 - ray.init reports a malformed address itself
        return address


def _check_route(address: str, timeout: float = 5.0) -> None:
    """Raise :class:`ClusterUnreachableError` when the cluster answers at ``address`` but not at the address this
    process's Ray would connect to instead (:func:`_ray_connects_to`).

    A cluster started with ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` has 127.0.0.1 as its node address and its GCS
    listens there only; a driver without that setting (Linux's default) turns ``127.0.0.1:PORT`` into
    ``<this machine's address>:PORT``, where nothing listens, and ``ray.init`` retries "Failed to connect to GCS" there
    for about 14 minutes (20 attempts of about 40 s each) before its first error. One TCP connection tells it at once.
    """
    target = _ray_connects_to(address)
    if target == address:
        return
    host, _, port = target.rpartition(":")
    t = time.monotonic()
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            return
    except (OSError, ValueError) as exc:
        said = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        raise ClusterUnreachableError(
            f"The Ray cluster at {address} answers there, but Ray in this process connects to {target} instead (Ray replaces "
            f"a loopback address by this machine's address unless {LOOPBACK_SETTING}=0 is set), and nothing answers there: "
            f"a TCP connection to {target} failed after {time.monotonic() - t:.1f} s ({said}). The cluster was most likely "
            f"started with {LOOPBACK_SETTING}=0 (its processes then listen on 127.0.0.1 only) and this process runs "
            f"without it: run this command with {LOOPBACK_SETTING}=0 too, with the cluster's Ray version ({_ray_version()} "
            f"here), or restart the cluster without the setting (its GCS then listens on every address of its machine)."
        ) from None


def _ray_version() -> str:
    try:
        return f"Ray {importlib.metadata.version('ray')}"
    except importlib.metadata.PackageNotFoundError:
        return "Ray's version"


def _token_found_here(loader: Any) -> bool:
    """Whether this process could send a Ray token (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH``, ``~/.ray/auth_token``),
    whatever ``RAY_AUTH_MODE`` says, leaving Ray's token cache as it was.

    Looking a token up keeps it in Ray's process-wide cache even when token authentication is off, and the gRPC
    server that ``ray.init`` starts later in this process (the driver's, which owns its ``ray.put`` objects) then
    refuses every request without that token. The raylets of a cluster without token authentication send none: asked
    where a driver's object is, they get ``InvalidAuthToken`` and report its owner dead (``OwnerDiedError``) for every
    task that needs the object on another node. A token is on any machine where a local Ray was ever started
    (``ray.init()`` writes ``~/.ray/auth_token``).
    """
    try:
        return loader.has_token(ignore_auth_mode=True)
    finally:
        loader.reset_cache()  # the next lookup (ray.init's) follows RAY_AUTH_MODE again


def _check_auth(address: str) -> None:
    """Fail at once, saying what to set, when the Ray cluster at ``host:port`` uses token authentication and this
    process cannot authenticate to it.

    ``ray.init`` would retry for about 20 s and then say only "Failed to connect" (the cause, ``InvalidAuthToken``,
    is in its log lines). Ray sends its token to an address the caller names only when ``RAY_AUTH_MODE=token`` is
    set (it turns token mode on by itself only for a cluster it finds on this machine, ``address="auto"``);
    hub-envs keeps that rule rather than sending a token found here to any address: a token is one cluster's
    credential. One request to the cluster's GCS (its cluster id) answers at once, or is refused for the token.
    """
    if "://" in address or address in ("auto", "local"):
        return  # Ray Client (ray://) authenticates in its own protocol; auto: Ray's own discovery and rules
    try:  # Ray's token authentication (in Ray 2.60); a Ray without it has nothing to check
        from ray._raylet import AuthenticationMode, AuthenticationTokenLoader, GcsClient, get_authentication_mode  # heavy: ray
        from ray.exceptions import AuthenticationError, RpcError  # heavy: ray
    except ImportError:
        return
    token_mode = get_authentication_mode() == AuthenticationMode.TOKEN
    has_token = _token_found_here(AuthenticationTokenLoader.instance())
    where = "RAY_AUTH_TOKEN, a file named by RAY_AUTH_TOKEN_PATH, or ~/.ray/auth_token"
    if token_mode and not has_token:  # (Ray's client aborts the whole process on a request in this state)
        raise ClusterAuthError(
            f"RAY_AUTH_MODE=token is set, but no Ray token was found here ({where}): nothing was sent to {address}. "
            f"Put the cluster's token in one of them (on the head node, `ray get-auth-token` prints it)."
        )
    try:
        GcsClient(address=address)
    except AuthenticationError as exc:
        said = getattr(exc, "message", str(exc))
        if token_mode:
            raise ClusterAuthError(
                f"The Ray cluster at {address} refused this process's Ray token ({said}): the token found here (the first "
                f"of {where}) is not this cluster's. Use the head node's (`ray get-auth-token` there prints it)."
            ) from None
        found = " (one was found here: it is sent once RAY_AUTH_MODE=token is set)" if has_token else f" in {where}"
        raise ClusterAuthError(
            f"The Ray cluster at {address} uses token authentication and this process sent no token ({said}). Ray sends "
            f"its token to an address you name only with RAY_AUTH_MODE=token: set it for this command, with the "
            f"cluster's token{found}; on the head node, `ray get-auth-token` prints it. See docs/scaling.md "
            f"('Running on a Ray cluster', steps 3 and 4)."
        ) from None
    except RpcError as exc:
        raise ClusterUnreachableError(
            f"Nothing at {address} answers as a Ray cluster ({exc}). Pass the address of the head node's GCS "
            f"(`ray start --head` prints it; port 6379 unless --port was given), not the dashboard's."
        ) from None


def worker_env() -> dict[str, str]:
    """The environment variables a run's Ray tasks get (Ray ``runtime_env``): the driver's Hub endpoint (as
    huggingface_hub resolved it here) and the :data:`HUB_SETTINGS` set here. A cluster someone else started (``ray
    start`` from a shell without them) would otherwise send its workers to huggingface.co. No secret goes here: a task's
    ``runtime_env`` is part of the cluster's job and task metadata (``ray list tasks --detail``, the dashboard)."""
    env = {"HF_ENDPOINT": hub_io.endpoint()}
    env.update({name: os.environ[name] for name in HUB_SETTINGS if os.environ.get(name)})
    return env


# --- the worker side ------------------------------------------------------------------------------

#: this worker process's envs (and policies), by run: (source identity, isolation, policy digest) -> _Loaded.
#: Ray reuses a worker process for the tasks of a job, so an env is loaded once per worker, not per shard.
_LOADED: dict[tuple[str, ...], Any] = {}
_KEEP = 2  # runs whose envs a worker keeps (a reproduce runs a replay pass, then maybe a checkpoint policy)


class _Loaded:
    """One run's env in this worker: loaded from its source (or the typed error that says why not)."""

    def __init__(self, source: EnvSource, policy: Any):
        self.error: HubEnvsError | None = None
        self.env = None
        self.loaded = None
        self.policy = policy
        self.scratch = tempfile.mkdtemp(prefix="hub-envs-worker-") if source.folder is not None else None
        try:
            self.loaded = source.load(self.scratch)  # with the driver's isolation: then self.env is a proxy
            if isinstance(policy, dict):  # a policy spec: built here, once per worker
                self.policy = policy_for(policy, self.loaded, source.token, True)  # consent was checked on the driver
            self.env = self.loaded.make()
        except HubEnvsError as exc:  # raised for every shard, naming this node
            self.error = type(exc)(f"on Ray node {_node_ip()}: {exc}")
        except Exception as exc:  # noqa: BLE001
            self.error = EnvCodeError(f"on Ray node {_node_ip()}: building the env raised {type(exc).__name__}: {exc}")

    def close(self) -> None:
        """Close the env (an isolated one's worker process ends with it), unregister it, remove the unpacked folder."""
        if self.env is not None:
            try:
                self.env.close()
            except Exception:  # noqa: BLE001
                pass
            self.env = None
        if self.loaded is not None:
            self.loaded.unregister()
            self.loaded = None
        if self.scratch is not None:
            shutil.rmtree(self.scratch, ignore_errors=True)
            self.scratch = None


def run_shard(
    key: tuple[str, ...], source: EnvSource, policy: Any, max_steps: int, record_states: bool, start: int, seeds: list, actions
) -> list[EpisodeRollout]:
    """Run one shard on a Ray worker: episodes ``start, start + 1, ...`` (one per seed) on this worker's env for the run ``key``
    (the env, and a policy spec's policy, built once per worker).

    Args:
        key: the run's key (source identity, isolation, policy digest).
        source: how this worker gets the env.
        policy: the policy (a spec is built here once), or None.
        max_steps, record_states: as :meth:`~hub_envs.backends.base.Backend.episodes`.
        start: the shard's first episode index.
        seeds: the shard's reset seeds.
        actions: recorded actions to replay, or None.

    Returns:
        The shard's rollouts, in order.

    Raises:
        HubEnvsError: the env could not be loaded on this node (the message names it).
    """
    here = _LOADED.get(key)
    if here is None:
        while len(_LOADED) >= _KEEP:
            _LOADED.pop(next(iter(_LOADED))).close()
        here = _LOADED[key] = _Loaded(source, policy)
    if here.error is not None:
        raise here.error
    env = here.env
    runner = EpisodeRunner(lambda: env, max_steps, actions if actions is not None else here.policy, record_states, len(seeds))
    return [runner.run(i, seed, episode=start + i) for i, seed in enumerate(seeds)]


def _node_ip() -> str:
    try:
        import ray  # heavy: ray

        return ray.util.get_node_ip_address()
    except Exception:  # noqa: BLE001
        return socket.gethostname()


# --- the driver side ------------------------------------------------------------------------------


def _policy_parts(policy: Any, n: int) -> tuple[Any, list | None]:
    """(what every actor gets once, per-episode actions to ship with each shard or None)."""
    if isinstance(policy, (list, tuple)) and len(policy) == n and all(p is None or isinstance(p, np.ndarray) for p in policy):
        return None, list(policy)
    return policy, None


def _digest(obj: Any) -> str:
    from ray import cloudpickle  # heavy: ray

    return hashlib.sha256(cloudpickle.dumps(obj)).hexdigest()


def alive_slots(ray: Any) -> tuple[int, int]:
    """What the cluster can run at once, from its node table (one GCS request). A shard takes one CPU; the count drops when
    a node dies (a worker process killed on a live node is restarted by Ray and does not count).

    Args:
        ray: the ``ray`` module, connected.

    Returns:
        ``(CPUs on the live nodes, live nodes)``.
    """
    nodes = [node for node in ray.nodes() if node.get("Alive")]
    return int(sum(node.get("Resources", {}).get("CPU", 0) for node in nodes)), len(nodes)


class _Status:
    """The progress bar's postfix: ``workers alive=<live>/<workers>, nodes=<n>`` (and resumed shards), refreshed
    at most every ``every`` seconds (the count asks the cluster)."""

    def __init__(self, ray: Any, bar: Any, workers: int, resumed: int, every: float = 2.0):
        self.ray, self.bar, self.workers, self.resumed, self.every = ray, bar, workers, resumed, every
        self.last = float("-inf")
        self.refresh()

    def refresh(self) -> None:
        now = time.monotonic()
        if now - self.last < self.every:
            return
        self.last = now
        try:
            cpus, nodes = alive_slots(self.ray)
        except Exception:  # noqa: BLE001 - a status line never fails a run
            return
        text = f"workers alive={min(cpus, self.workers)}/{self.workers}, nodes={nodes}"
        if self.resumed:
            text += f", resumed shards={self.resumed}"
        self.bar.set_postfix_str(text)


class RayRun:
    """One run's iterator of rollouts (in episode order); ``stats`` counts shards run and resumed."""

    def __init__(self, it: Iterator[EpisodeRollout], stats: dict[str, int]):
        self._it = it
        self.stats = stats

    def __iter__(self) -> RayRun:
        return self

    def __next__(self) -> EpisodeRollout:
        return next(self._it)

    def close(self) -> None:
        """Cancel the shards in flight: nothing is left running."""
        self._it.close()


class RayBackend(Backend):
    """Episodes on a Ray cluster (see the module docstring). Results equal :class:`~hub_envs.backends.LocalBackend`'s."""

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        checkpoint_dir: str | Path | None = None,
        shard_size: int | None = None,
        object_store_memory: int | None = None,
        worker_niceness: int | None = None,
        send_token: bool | None = None,
    ):
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
            raise ConfigError(f"workers={workers!r}: pass a positive number of Ray actors (0 or None: the cluster's CPUs).")
        if shard_size is not None and shard_size < 1:
            raise ConfigError(f"shard_size={shard_size!r}: pass a positive number of episodes per shard.")
        check_ray_installed()
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        self.workers = workers or None
        self.checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir is not None else None
        self.shard_size = shard_size
        self.object_store_memory = object_store_memory
        #: the niceness of a local Ray's workers (None: Ray's own default, 15; a cluster you start sets its own)
        self.worker_niceness = worker_niceness
        #: whether the workers get the driver's Hub token (None: ``$HUB_ENVS_RAY_SEND_TOKEN``, default yes)
        self.send_token = _send_token_setting() if send_token is None else bool(send_token)
        if self.address:  # commands make their backend first: a cluster that cannot be used fails them before any work
            self.preflight()
        self._depth = 0
        self._runs: weakref.WeakSet[RayRun] = weakref.WeakSet()  # runs not finished yet: closed on __exit__
        self._started = False
        self.startup_seconds: float | None = None

    def __repr__(self) -> str:
        return f"RayBackend(address={self.address!r}, workers={self.workers!r})"

    def preflight(self) -> None:
        """Raise the typed error now if nothing answers at :attr:`address`, or Ray in this process would connect to
        another address where nothing answers (a cluster started with ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``, this
        process without it: :class:`ClusterUnreachableError`), or the cluster refuses this process
        (:class:`ClusterAuthError`, saying what to set); nothing is started."""
        _probe(self.address)
        _check_route(self.address)
        _check_auth(self.address)

    def worker_token(self, token: str | None) -> str | None:
        """The Hub token the workers download with.

        It travels inside the env's source through Ray's object store (memory of the nodes that run the job, and their spill
        folder on disk when the store is full), never in the job's or the tasks' metadata.

        Args:
            token: the load's own token.

        Returns:
            ``token``, else the one huggingface_hub finds here (``HF_TOKEN``, ``$HF_HOME/token``); None when
            :attr:`send_token` is off (the workers use their node's).
        """
        if not self.send_token:
            return None
        if token:
            return token

        return get_token()

    # -- the connection --
    def __enter__(self) -> RayBackend:
        ray = import_ray()
        if self._depth == 0 and self.address:
            _probe(self.address)  # also when connected already: a wrong address is never silently ignored
        if self._depth == 0 and not ray.is_initialized():
            t = time.perf_counter()
            os.environ.setdefault("RAY_DEDUP_LOGS", "0")
            if self.address:
                _check_route(self.address)  # (again: the cluster may have changed since the backend was made)
                _check_auth(self.address)
                self._connect(ray)
            else:
                ray.init(
                    address="local",  # a new Ray for this run, never a cluster some earlier ray.init left behind
                    num_cpus=self.workers or None,
                    include_dashboard=False,
                    log_to_driver=False,
                    logging_level="warning",
                    object_store_memory=self.object_store_memory,
                    # Ray's default nice 15 kept: measured side by side on a loaded machine, nice 0 was not faster
                    # (ray_vs_local_reproduce 0.69 at nice 0 against 0.90 at nice 15 in one run; docs/scaling.md)
                    **(
                        {"_system_config": {"worker_niceness": int(self.worker_niceness)}}
                        if self.worker_niceness is not None
                        else {}
                    ),
                )
            self._started = True
            self.startup_seconds = time.perf_counter() - t
        self._depth += 1
        return self

    def _connect(self, ray: Any) -> None:
        """``ray.init`` to :attr:`address`, in a bounded time: Ray's own bound on its attempts to reach the GCS
        (:data:`GCS_ATTEMPTS`, unless ``RAY_gcs_server_port_wait_time_s`` is set here), a typed error saying what was
        tried, and nothing of Ray left half-initialised on the way out."""
        ours = GCS_ATTEMPTS_VAR not in os.environ
        if ours:
            os.environ[GCS_ATTEMPTS_VAR] = str(GCS_ATTEMPTS)  # read when ray.init connects (node.py, _init_gcs_client)
        t = time.monotonic()
        try:
            ray.init(address=self.address, log_to_driver=False, logging_level="warning")
        except ConnectionError as exc:
            ray.shutdown()  # a no-op unless Ray kept part of the connection
            target = _ray_connects_to(self.address)
            via = f" (which Ray in this process turned into {target})" if target != self.address else ""
            raise ClusterUnreachableError(
                f"Ray at {self.address}{via} did not let this process connect: ray.init tried for "
                f"{time.monotonic() - t:.0f} s ({os.environ.get(GCS_ATTEMPTS_VAR)} attempts to reach its GCS, "
                f"{GCS_ATTEMPTS_VAR}) and said: {exc}. Check that the cluster is up (`ray status` on the head), that this "
                f"process runs the cluster's Ray version ({_ray_version()} here) and its {LOOPBACK_SETTING} setting; "
                f"Ray's log lines above say what failed."
            ) from None
        finally:
            if ours:
                os.environ.pop(GCS_ATTEMPTS_VAR, None)

    def __exit__(self, *exc: Any) -> None:
        first: BaseException | None = None
        if self._depth == 1:
            # an exception (Ctrl-C in the consumer, an error writing the dataset) leaves runs suspended at a yield,
            # kept alive by the traceback: close them now, so their shards are cancelled before Ray is shut down
            for run in list(self._runs):
                if not run._it.gi_running:  # (a run's own ``with self`` exits while it runs: it cleans up itself)
                    try:
                        run.close()
                    except BaseException as e:  # noqa: BLE001 - every run is closed and Ray shut down, then raised
                        first = first or e
        self._depth -= 1
        if self._depth == 0 and self._started:
            import ray  # heavy: ray

            ray.shutdown()
            self._started = False
        if first is not None:
            raise first

    def settings(self) -> dict[str, Any]:
        """``{"backend": "ray", "workers": n, "address": ...}``: where a report says the episodes ran."""
        return {"backend": self.name, "workers": self.workers, "address": self.address}

    def _n_workers(self, ray: Any, n_episodes: int) -> int:
        n = self.workers or int(ray.cluster_resources().get("CPU", 1))
        return max(1, min(n, n_episodes))

    # -- a run --
    def episodes(self, loaded, seeds, *, max_steps, policy=None, record_states=False, progress=True, desc="rollouts") -> RayRun:
        """As :meth:`~hub_envs.backends.base.Backend.episodes`, sharded across the cluster, consumed in shard order.

        Args:
            loaded, seeds, max_steps, policy, record_states, progress, desc: as :meth:`~hub_envs.backends.base.Backend.episodes`.

        Returns:
            A :class:`RayRun` (an iterator of the rollouts; closing it cancels the shards in flight).

        Raises:
            ClusterUnreachableError, ClusterAuthError: the cluster cannot be used.
            MissingRequirementsError: Ray is not installed.
        """
        seeds = check_seeds(seeds)
        if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
            raise ConfigError(f"max_steps={max_steps!r}: pass a positive integer.")
        stats = {"episodes": len(seeds), "shards": 0, "shards_run": 0, "shards_resumed": 0}
        run = RayRun(self._run(loaded, seeds, int(max_steps), policy, bool(record_states), progress, desc, stats), stats)
        self._runs.add(run)
        return run

    def _run(self, loaded, seeds, max_steps, policy, record_states, progress, desc, stats) -> Iterator[EpisodeRollout]:
        with self:
            ray = import_ray()
            n = len(seeds)
            workers = self._n_workers(ray, n)
            size = self.shard_size or max(1, min(MAX_SHARD_SIZE, -(-n // (4 * workers))))
            shards = [(s, seeds[s : s + size]) for s in range(0, n, size)]
            stats["shards"] = len(shards)
            shared, per_episode = _policy_parts(policy, n)
            source = EnvSource.from_loaded(loaded)
            if source.folder is None:  # a Hub repo, which each worker downloads (private: with a token)
                source = dataclasses.replace(source, token=self.worker_token(source.token))
            ckpt = self._checkpoints(source, seeds, max_steps, policy, record_states, size)
            done = {k for k in range(len(shards)) if ckpt is not None and (ckpt / f"shard-{k:06d}.pkl").is_file()}
            todo = deque(k for k in range(len(shards)) if k not in done)
            bar = progress_bar(n, desc, progress)
            status = _Status(ray, bar, workers, resumed=len(done)) if progress else None
            pending: dict[int, Any] = {}
            task = ray.remote(num_cpus=1, max_retries=MAX_RESTARTS, runtime_env={"env_vars": worker_env()})(run_shard)
            source_ref = ray.put(source)
            policy_ref = ray.put(shared)
            # a worker's cached env is per (content, isolation, policy): an isolated and an in-process run of one
            # env never share it
            key = (source.identity, json.dumps(source.isolation, sort_keys=True), _digest(shared))
            window = 2 * workers
            try:

                def submit() -> None:
                    while todo and len(pending) < window:
                        k = todo.popleft()
                        start, shard_seeds = shards[k]
                        actions = per_episode[start : start + len(shard_seeds)] if per_episode is not None else None
                        pending[k] = task.remote(
                            key, source_ref, policy_ref, max_steps, record_states, start, shard_seeds, actions
                        )

                for k in range(len(shards)):
                    submit()
                    if k in done:
                        rollouts = pickle.loads((ckpt / f"shard-{k:06d}.pkl").read_bytes())
                        stats["shards_resumed"] += 1
                    else:
                        rollouts = self._get(ray, pending.pop(k), loaded)
                        stats["shards_run"] += 1
                        if ckpt is not None:
                            tmp = ckpt / f".shard-{k:06d}.pkl.tmp"
                            tmp.write_bytes(pickle.dumps(rollouts, protocol=pickle.HIGHEST_PROTOCOL))
                            os.replace(tmp, ckpt / f"shard-{k:06d}.pkl")
                    if status is not None:
                        status.refresh()
                    for rollout in rollouts:
                        bar.update(1)
                        yield rollout
            finally:
                for ref in pending.values():  # also on Ctrl-C / an early close: nothing keeps running
                    ray.cancel(ref, force=True)
                bar.close()

    @staticmethod
    def _get(ray: Any, ref: Any, loaded: Any) -> list[EpisodeRollout]:
        try:
            return ray.get(ref)
        except ray.exceptions.RayTaskError as exc:
            cause = getattr(exc, "cause", None)
            if isinstance(cause, HubEnvsError):
                raise cause from None
            raise EnvCodeError(f"{loaded.repo_id}@{loaded.revision}: a Ray worker raised: {exc}") from None
        except (ray.exceptions.WorkerCrashedError, ray.exceptions.RayActorError) as exc:
            raise EnvCodeError(
                f"{loaded.repo_id}@{loaded.revision}: a Ray worker could not start, or died {MAX_RESTARTS + 1} times "
                f"running the same shard (the env crashes the interpreter, the node ran out of memory, or the policy "
                f"cannot be unpickled there): {exc}. Run with --backend=local --workers=1 to see the failure in this process."
            ) from None

    def _checkpoints(self, source: EnvSource, seeds, max_steps, policy, record_states, size) -> Path | None:
        if self.checkpoint_dir is None:
            return None
        key = hashlib.sha256(
            json.dumps(
                {
                    "env": source.identity,
                    "config": source.config,
                    "seeds": seeds,
                    "max_steps": max_steps,
                    "record_states": record_states,
                    "shard_size": size,
                    "policy": _digest(policy),
                },
                sort_keys=True,
                default=str,
            ).encode()
        ).hexdigest()[:20]
        folder = self.checkpoint_dir / f"run-{key}"
        folder.mkdir(parents=True, exist_ok=True)
        return folder
