"""Every version-dependent reach into huggingface_hub, lerobot, draccus, gymnasium and the stdlib, and every use of an
upstream name that is not public (``tests/test_compat.py`` fails when upstream moves one).

Example:
    >>> from hub_envs import _compat
    >>> _compat.HF_HUB_MAJOR >= 0
    True
    >>> isinstance(_compat.NETWORK_ERRORS, tuple)
    True
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import sys
from collections.abc import Callable, Mapping
from importlib.util import find_spec
from pathlib import Path
from typing import Any

import huggingface_hub
from huggingface_hub import constants
from packaging.version import Version


def _version(dist: str) -> Version | None:
    from importlib.metadata import PackageNotFoundError, version  # heavy-ish: importlib.metadata (email, zipfile, csv)

    try:
        return Version(version(dist))
    except PackageNotFoundError:
        return None


# --- huggingface_hub: requests (0.x) or httpx (1.x) --------------------------------------------

HF_HUB_VERSION: Version = Version(huggingface_hub.__version__)  # the package's own (its distribution's version)
HF_HUB_MAJOR: int = HF_HUB_VERSION.major


def _network_errors() -> tuple[tuple[type[BaseException], ...], tuple[type[BaseException], ...]]:
    """``(cannot reach the Hub, transfer broke off)`` exception classes of the client's HTTP library.

    *Cannot reach*: no connection, a timeout, or the connection refused or reset while a request was
    in flight (the server died or went away): requests' ``ConnectionError`` / ``Timeout``; httpx's
    ``NetworkError`` (``ConnectError``, ``ReadError``, ``WriteError``, ``CloseError``),
    ``TimeoutException`` and ``ProxyError``. A server killed while it reads a request resets the
    connection: requests raises ``ConnectionError``, httpx ``ReadError`` / ``WriteError``.

    *Broke off*: everything else the HTTP library raises, chiefly a response body cut off mid-file
    (requests' ``ChunkedEncodingError``, httpx's ``RemoteProtocolError`` "peer closed connection
    without sending complete message body"). httpx's classes cannot tell where a failure happened,
    so two edge cases differ from requests: a server closing (not resetting) the connection before
    answering is a ``RemoteProtocolError`` ("Server disconnected without sending a response") and
    reads as *broke off*; a connection reset mid-body is a ``ReadError`` and reads as *cannot reach*.
    """
    if HF_HUB_MAJOR >= 1:
        import httpx  # heavy: httpx

        network = (httpx.NetworkError, httpx.TimeoutException, httpx.ProxyError)
        return network, (httpx.TransportError, httpx.DecodingError, httpx.StreamError)
    import requests  # heavy: requests

    return (requests.ConnectionError, requests.Timeout), (requests.RequestException,)


#: ``NETWORK_ERRORS``: the Hub cannot be reached (connection refused or reset, DNS, timeout).
#: ``TRANSFER_ERRORS``: the transfer broke off after it started (e.g. a connection dropped mid-file).
#: Catch ``NETWORK_ERRORS`` first: with requests, ``TRANSFER_ERRORS`` includes it.
#: Both are made on first use (:func:`__getattr__`): the HTTP library is imported only where the Hub is talked to.
NETWORK_ERRORS: tuple[type[BaseException], ...]
TRANSFER_ERRORS: tuple[type[BaseException], ...]


def __getattr__(name: str) -> Any:
    """``NETWORK_ERRORS`` and ``TRANSFER_ERRORS`` (importing the HTTP library), and ``LEROBOT_VERSION`` (reading the
    installed distributions), made when first asked for."""
    if name in ("NETWORK_ERRORS", "TRANSFER_ERRORS"):
        network, transfer = _network_errors()
        globals().update(NETWORK_ERRORS=network, TRANSFER_ERRORS=transfer)
        return globals()[name]
    if name == "LEROBOT_VERSION":
        if name not in globals():  # asked through _lerobot_at_least too: read once
            globals()[name] = _version("lerobot")
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def file_get_retries_server_errors() -> bool:
    """Whether the client retries a 5xx answer to the ``GET`` of a file's content (``hf_hub_download``).

    0.x: yes. Both the metadata ``HEAD`` and the content ``GET`` of ``.../resolve/...`` go through
    ``http_backoff``, which retries 500/502/503/504 and connection errors up to 5 times.
    1.x: no. ``http_get`` calls ``http_stream_backoff(..., retry_on_status_codes=(408, 429))``, so a
    5xx on the ``GET`` fails the download at once (a body cut off mid-file is resumed instead, up to
    5 times). A 5xx on the metadata ``HEAD`` is still retried: after the first failure, unless
    ``force_download=True``, ``hf_hub_download`` asks again with ``retry_on_errors=True``
    (``http_backoff``: 408, 429, 5xx and network errors, up to 5 more times).
    """
    return HF_HUB_MAJOR < 1


@contextlib.contextmanager
def lfs_instead_of_xet(enabled: bool = True):
    """Inside the block, huggingface_hub uploads large files through Git LFS, not Xet (both versions read
    ``constants.HF_HUB_DISABLE_XET`` at each upload). Process-wide while it lasts.

    Args:
        enabled: False: change nothing.
    """
    if not enabled or constants.HF_HUB_DISABLE_XET:
        yield
        return
    constants.HF_HUB_DISABLE_XET = True
    try:
        yield
    finally:
        constants.HF_HUB_DISABLE_XET = False


def reset_http_sessions() -> None:
    """Drop the client's cached HTTP sessions (0.x ``reset_sessions``, 1.x ``close_session``)."""
    from huggingface_hub import utils  # heavy: huggingface_hub's HTTP stack

    reset = getattr(utils, "close_session", None) or utils.reset_sessions
    reset()


@contextlib.contextmanager
def stream_file(url: str, headers: Mapping[str, str], timeout: float):
    """``GET url`` through huggingface_hub's own HTTP client (its session, hooks and proxies), redirects followed, the body
    streamed. A redirect to another host drops the ``Authorization`` header (both libraries do).

    Args:
        url: the URL.
        headers: the request's headers.
        timeout: seconds.

    Yields:
        ``(status, hub_headers, final_headers, chunks)``: ``hub_headers`` of the first answer (the Hub's own, with
        ``X-Repo-Commit`` / ``X-Linked-Etag`` even when it redirects a large file to a CDN), ``final_headers`` of the
        answer that carries the body, ``chunks`` an iterator of its bytes.
    """
    from huggingface_hub.utils import get_session  # heavy: huggingface_hub's HTTP stack

    session = get_session()
    if HF_HUB_MAJOR >= 1:
        with session.stream("GET", url, headers=dict(headers), follow_redirects=True, timeout=timeout) as response:
            first = response.history[0] if response.history else response
            yield response.status_code, first.headers, response.headers, response.iter_bytes(2**20)
        return
    response = session.get(url, headers=dict(headers), stream=True, allow_redirects=True, timeout=timeout)
    try:
        first = response.history[0] if response.history else response
        yield response.status_code, first.headers, response.headers, response.iter_content(2**20)
    finally:
        response.close()


def install_response_hook(hook) -> bool:
    """Run ``hook(method, url, status, headers, read_body)`` on every HTTP response huggingface_hub's client receives: each hop
    of a redirect chain, whether the client (1.x's metadata ``HEAD``, 0.35's relative redirects) or its HTTP library
    (``GET``) follows it. 0.x: a ``requests`` response hook on every session its backend factory makes
    (``configure_http_backend``); 1.x: an ``httpx`` event hook on the clients of ``set_client_factory``. Whatever factory
    was configured before (by the user or another library) is kept and wrapped. Reads the current factory from a
    private name (``_GLOBAL_BACKEND_FACTORY`` / ``_GLOBAL_CLIENT_FACTORY``): huggingface_hub has no getter.

    Args:
        hook: called with the request's method, the URL this answer came from, its status and headers, and
            ``read_body()`` (call it only for small API answers, never for file downloads). An exception it raises
            propagates out of the client call before the client uses the response.

    Returns:
        True when it installed the hook now (idempotent per hook).
    """
    import huggingface_hub  # heavy: huggingface_hub's HTTP stack (httpx or requests)
    from huggingface_hub.utils import _http

    name = "_GLOBAL_CLIENT_FACTORY" if HF_HUB_MAJOR >= 1 else "_GLOBAL_BACKEND_FACTORY"
    previous = getattr(_http, name)
    if hook in getattr(previous, "_hub_envs_hooks", ()):
        return False

    if HF_HUB_MAJOR >= 1:

        def on_response(response) -> None:
            request = response.request
            hook(request.method, str(request.url), response.status_code, response.headers, lambda: response.read())

        def factory():
            client = previous()
            client.event_hooks = {**client.event_hooks, "response": [*client.event_hooks.get("response", []), on_response]}
            return client

        factory._hub_envs_hooks = (*getattr(previous, "_hub_envs_hooks", ()), hook)
        huggingface_hub.set_client_factory(factory)  # also closes the current client
    else:

        def on_response(response, *args, **kwargs):
            method = response.request.method if response.request is not None else "GET"
            hook(method, response.url, response.status_code, response.headers, lambda: response.content)
            return response

        def factory():
            session = previous()
            session.hooks.setdefault("response", []).append(on_response)
            return session

        factory._hub_envs_hooks = (*getattr(previous, "_hub_envs_hooks", ()), hook)
        huggingface_hub.configure_http_backend(backend_factory=factory)  # also resets the sessions
    return True


# --- lerobot -----------------------------------------------------------------------------------

#: The installed lerobot's version (None: not installed), read on first use (:func:`__getattr__`).
LEROBOT_VERSION: Version | None


def _lerobot_at_least(version: str) -> bool:
    """Whether the installed lerobot is at least ``version``."""
    lerobot = __getattr__("LEROBOT_VERSION")
    return lerobot is not None and lerobot >= Version(version)


def env_config_choices() -> dict[str, Any]:
    """LeRobot's ``EnvConfig`` draccus choices, name -> class, as a live dict.

    ``EnvConfig.get_known_choices()`` is public and returns the registry itself on draccus 0.10 and
    0.11; hub-envs mutates it to unregister what it registered (draccus has no public unregister),
    so this checks it really is the live registry and not a copy.
    """
    from lerobot.envs.configs import EnvConfig  # heavy: lerobot (torch)

    choices = EnvConfig.get_known_choices()
    if choices is not getattr(EnvConfig, "_choice_registry", None):  # pragma: no cover - upstream change
        raise RuntimeError(
            "draccus' EnvConfig.get_known_choices() no longer returns the live registry; "
            "update hub_envs._compat.env_config_choices."
        )
    return choices


#: The package of LeRobot's ``EnvConfig`` and its draccus choice registry (``--env.type``, in ``lerobot.envs.configs``),
#: in every supported version: whatever parses a LeRobot config imports it first, and its import ends after its
#: ``configs`` module ran, so a hook on it (:func:`after_import`) runs once ``EnvConfig`` is there and complete.
LEROBOT_ENV_PACKAGE = "lerobot.envs"


def lerobot_env_configs_imported() -> bool:
    """Whether LeRobot's ``EnvConfig`` (:data:`LEROBOT_ENV_PACKAGE`) is imported in this process (asking imports nothing)."""
    package, configs = sys.modules.get(LEROBOT_ENV_PACKAGE), sys.modules.get(f"{LEROBOT_ENV_PACKAGE}.configs")
    return package is not None and not getattr(package.__spec__, "_initializing", False) and hasattr(configs, "EnvConfig")


class _ThenCall:
    """A module's loader that calls ``callback(module)`` once the module has run (and hands the module its own loader
    back): what :func:`after_import` puts in the module's spec."""

    def __init__(self, loader: Any, callback: Callable[[Any], None]):
        self._loader, self._callback = loader, callback

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        module.__loader__ = module.__spec__.loader = self._loader  # the module keeps its real loader (get_source, ...)
        self._callback(module)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._loader, name)


class _AfterImport:
    """A ``sys.meta_path`` finder that finds nothing itself: for one module it asks the finders after it for the spec
    and wraps the spec's loader in :class:`_ThenCall` (the stdlib has no post-import hook)."""

    def __init__(self, name: str, callback: Callable[[Any], None]):
        self.name, self.callback = name, callback

    def find_spec(self, fullname: str, path=None, target=None):
        if fullname != self.name:
            return None
        for finder in sys.meta_path:
            find = getattr(finder, "find_spec", None)
            if finder is self or isinstance(finder, _AfterImport) or find is None:
                continue
            spec = find(fullname, path, target)
            if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
                spec.loader = _ThenCall(spec.loader, self.callback)
                return spec
            if spec is not None:
                return spec
        return None


def after_import(name: str, callback: Callable[[Any], None]) -> None:
    """Call ``callback(module)`` right after the module ``name`` is imported, by whoever imports it: at once if it is
    imported already. Once per module and callback (a second call with the same pair does nothing).

    Args:
        name: a full module name (``"lerobot.envs"``).
        callback: called with the module, inside the import statement that imports it: it must not raise.
    """
    module = sys.modules.get(name)
    if module is not None:
        callback(module)
        return
    if not any(isinstance(f, _AfterImport) and f.name == name and f.callback == callback for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterImport(name, callback))


def processor_step_names() -> list[str]:
    """Names in LeRobot's ``ProcessorStepRegistry`` (public ``list()`` on every supported version)."""
    from lerobot.processor.pipeline import ProcessorStepRegistry  # heavy: lerobot (torch)

    return ProcessorStepRegistry.list()


def hf_transform_to_torch():
    """LeRobot's dataset transform to torch tensors (``datasets.utils`` in 0.4, ``datasets.io_utils`` from 0.5)."""
    try:
        from lerobot.datasets.io_utils import hf_transform_to_torch as fn  # heavy: lerobot (torch)
    except ImportError:
        from lerobot.datasets.utils import hf_transform_to_torch as fn  # heavy: lerobot (torch)
    return fn


def lerobot_dataset_io():
    """The LeRobot module with its dataset metadata readers (``load_info``, ``load_episodes``, ``load_stats``,
    ``load_tasks``): ``lerobot.datasets.utils`` in 0.4, ``lerobot.datasets.io_utils`` from 0.5 (where
    ``load_info`` returns a ``DatasetInfo`` that drops keys LeRobot does not know, such as ``hub_envs``)."""
    try:
        from lerobot.datasets import io_utils as module  # heavy: lerobot (torch)
    except ImportError:
        from lerobot.datasets import utils as module  # heavy: lerobot (torch)
    return module


def lerobot_dataset_layout() -> dict[str, Any]:
    """The v3.0 layout constants of the installed lerobot, under the names :mod:`hub_envs.dataset.layout` uses.

    hub-envs keeps its own copy (the file format is a contract its writer and reader must not change
    silently with an upgrade); ``tests/test_dataset.py`` compares the two on every stack. ``CODEBASE_VERSION``
    lives in ``lerobot_dataset`` up to 0.4 and ``dataset_metadata`` from 0.5; ``DEFAULT_FEATURES`` in
    ``datasets.utils`` up to 0.4 and ``utils.constants`` from 0.5.
    """
    from lerobot.datasets import utils  # heavy: lerobot (torch)

    try:
        from lerobot.datasets.dataset_metadata import CODEBASE_VERSION  # heavy: lerobot (torch)
    except ImportError:
        from lerobot.datasets.lerobot_dataset import CODEBASE_VERSION  # heavy: lerobot (torch)
    try:
        from lerobot.utils.constants import DEFAULT_FEATURES  # heavy: lerobot (torch)
    except ImportError:
        from lerobot.datasets.utils import DEFAULT_FEATURES  # heavy: lerobot (torch)
    return {
        "CODEBASE_VERSION": CODEBASE_VERSION,
        "DEFAULT_CHUNK_SIZE": utils.DEFAULT_CHUNK_SIZE,
        "DEFAULT_DATA_FILE_SIZE_IN_MB": utils.DEFAULT_DATA_FILE_SIZE_IN_MB,
        "DEFAULT_VIDEO_FILE_SIZE_IN_MB": utils.DEFAULT_VIDEO_FILE_SIZE_IN_MB,
        "INFO_PATH": utils.INFO_PATH,
        "STATS_PATH": utils.STATS_PATH,
        "TASKS_PATH": utils.DEFAULT_TASKS_PATH,
        "EPISODES_DIR": utils.EPISODES_DIR,
        "DATA_DIR": utils.DATA_DIR,
        "CHUNK_FILE_PATTERN": utils.CHUNK_FILE_PATTERN,
        "EPISODES_PATH": utils.DEFAULT_EPISODES_PATH,
        "DATA_PATH": utils.DEFAULT_DATA_PATH,
        "VIDEO_DIR": utils.VIDEO_DIR,
        "VIDEO_PATH": utils.DEFAULT_VIDEO_PATH,
        "DEFAULT_FEATURES": {k: {**v, "shape": list(v["shape"])} for k, v in DEFAULT_FEATURES.items()},
    }


def tasks_index_name() -> str | None:
    """The name of ``meta/tasks.parquet``'s index (the task strings) as the installed LeRobot writes it:
    unnamed in 0.4 (stored as ``__index_level_0__``), ``"task"`` from 0.5. Both read back the same."""
    return "task" if _lerobot_at_least("0.5") else None


def stats_extremes_as_float() -> bool:
    """Whether the installed LeRobot's writer stores the min/max stats of every numeric feature as float64
    (0.5 on: its running statistics work in float64) rather than in the feature's dtype (0.4: bool for
    ``next.done``, int64 for ``frame_index``), in ``meta/episodes`` and ``meta/stats.json``."""
    return _lerobot_at_least("0.5")


def train_dataset_hooks() -> tuple[str, ...]:
    """Names in ``lerobot.scripts.lerobot_train`` that build the training dataset.

    0.4 calls ``make_dataset(cfg)``; from 0.5 it calls ``make_train_eval_datasets(cfg)``, which returns
    ``(train, eval_or_None)``.
    """
    from lerobot.scripts import lerobot_train  # heavy: lerobot (torch)

    return tuple(name for name in ("make_dataset", "make_train_eval_datasets") if hasattr(lerobot_train, name))


def route_lerobot_scripts(
    make_env: Callable[..., Any],
    make_env_pre_post_processors: Callable[..., Any],
    dataset_hooks: Mapping[str, Callable[..., Any]],
) -> None:
    """Make ``lerobot_train`` and ``lerobot_eval`` build envs and env processors with these functions, and
    ``lerobot_train`` its dataset with ``dataset_hooks[name]`` for each builder it calls (:func:`train_dataset_hooks`).

    LeRobot's scripts hold these as module globals (``from lerobot.envs.factory import make_env``), so a plugin routes
    them only by replacing those globals; the same names in 0.4 and 0.6. Idempotent.

    Args:
        make_env: replaces ``make_env`` in both scripts.
        make_env_pre_post_processors: replaces ``make_env_pre_post_processors`` in both scripts.
        dataset_hooks: ``{"make_dataset": ..., "make_train_eval_datasets": ...}``.
    """
    from lerobot.scripts import lerobot_eval, lerobot_train  # heavy: lerobot (torch)

    for module in (lerobot_eval, lerobot_train):
        module.make_env = make_env
        module.make_env_pre_post_processors = make_env_pre_post_processors
    for name in train_dataset_hooks():
        setattr(lerobot_train, name, dataset_hooks[name])


def missing_training_packages() -> list[str]:
    """Packages LeRobot's training loop needs that are not installed: from 0.5 they are its ``training``
    extra (``accelerate`` is required at start; 0.4 has it in its core dependencies)."""
    return [name for name in ("accelerate",) if find_spec(name) is None]


def train_eval_freq_flag() -> str:
    """``lerobot-train``'s flag for how often to evaluate in the env: ``eval_freq`` in 0.4, ``env_eval_freq`` from 0.5."""
    from lerobot.configs.train import TrainPipelineConfig  # heavy: lerobot (torch)

    names = {f.name for f in dataclasses.fields(TrainPipelineConfig)}
    return "env_eval_freq" if "env_eval_freq" in names else "eval_freq"


#: where each LeRobot pipeline config ``hub-envs train``/``eval`` runs is defined, in LeRobot's package
LEROBOT_PIPELINE_CONFIGS = {
    "train": ("configs/train.py", "TrainPipelineConfig"),
    "eval": ("configs/eval.py", "EvalPipelineConfig"),
}


def lerobot_pipeline_flags(command: str) -> frozenset[str] | None:
    """The top-level flags of ``lerobot-train`` (``command="train"``) or ``lerobot-eval`` (``"eval"``): the init fields
    of their pipeline config, read from LeRobot's source without importing it (importing LeRobot imports torch:
    seconds before a mistyped flag could be named).

    Args:
        command: ``"train"`` or ``"eval"``.

    Returns:
        The field names, or None when LeRobot's source cannot be read this way (not installed, or moved): LeRobot's
        own parser judges the flags then.
    """
    spec = find_spec("lerobot")  # a top-level package: found, not imported
    if spec is None or not spec.submodule_search_locations:
        return None
    relpath, name = LEROBOT_PIPELINE_CONFIGS[command]
    try:
        tree = ast.parse((Path(next(iter(spec.submodule_search_locations))) / relpath).read_text(encoding="utf-8"))
    except (OSError, SyntaxError, ValueError):
        return None
    classes = {node.name: node for node in tree.body if isinstance(node, ast.ClassDef)}
    if name not in classes:
        return None
    names: set[str] = set()
    pending = [classes[name]]
    while pending:
        cls = pending.pop()
        pending += [classes[b.id] for b in cls.bases if isinstance(b, ast.Name) and b.id in classes]  # bases here
        for stmt in cls.body:
            if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
                continue
            if "ClassVar" in ast.unparse(stmt.annotation):
                continue
            if isinstance(stmt.value, ast.Call) and any(
                k.arg == "init" and isinstance(k.value, ast.Constant) and k.value.value is False for k in stmt.value.keywords
            ):  # field(init=False): no flag
                continue
            names.add(stmt.target.id)
    return frozenset(names) or None


def env_configs_create_envs() -> bool:
    """LeRobot >= 0.5 builds envs with ``EnvConfig.create_envs()`` and env processors with
    ``EnvConfig.get_env_processors()`` (0.4 has neither: its factory branches on the config type)."""
    from lerobot.envs.configs import EnvConfig  # heavy: lerobot (torch)

    return hasattr(EnvConfig, "create_envs") and hasattr(EnvConfig, "get_env_processors")


def lerobot_video_utils():
    """``lerobot.datasets.video_utils`` (the same module path in 0.4 and 0.6): LeRobot's own video encoder
    (``encode_video_frames``: a folder of ``frame-000000.png`` files -> one MP4 with pyav; default libsvtav1,
    yuv420p, GOP 2, CRF 30 in both), ``concatenate_video_files`` (remux, no re-encode) and
    ``get_video_duration_in_s``, all with the same signatures in the calls hub-envs makes."""
    from lerobot.datasets import video_utils  # heavy: lerobot (torch)

    return video_utils


#: LeRobot's GOP (keyframe interval) for camera videos, the same in 0.4 and 0.6; a video feature whose ``info``
#: records no ``video.g`` was encoded with it (0.6's ``VideoEncoderConfig.from_video_info`` reads it so too)
LEROBOT_VIDEO_GOP = 2


def _rgb_encoder(gop: int):
    """LeRobot >= 0.5's RGB encoder settings with GOP ``gop`` (None on 0.4, whose encoder takes ``g=`` itself)."""
    try:
        from lerobot.configs.video import rgb_encoder_defaults  # heavy: lerobot (torch)
    except ImportError:
        return None
    return dataclasses.replace(rgb_encoder_defaults(), g=int(gop))


def encode_video_frames(imgs_dir: Path, video_path: Path, fps: int, *, gop: int) -> None:
    """LeRobot's ``encode_video_frames`` with its defaults (libsvtav1, yuv420p, CRF 30) and GOP ``gop``: 0.4 takes ``g=``, 0.6
    a ``video_encoder=`` config. ``gop == LEROBOT_VIDEO_GOP`` gives LeRobot's own bytes.

    Args:
        imgs_dir: a folder of ``frame-000000.png`` files.
        video_path: the MP4 to write.
        fps: frames per second.
        gop: the keyframe interval.
    """
    video_utils = lerobot_video_utils()
    encoder = _rgb_encoder(gop)
    if encoder is None:
        video_utils.encode_video_frames(imgs_dir, video_path, fps, g=int(gop), overwrite=True)
    else:
        video_utils.encode_video_frames(imgs_dir, video_path, fps, video_encoder=encoder, overwrite=True)


def lerobot_video_info(video_path: str | Path, gop: int = LEROBOT_VIDEO_GOP) -> dict[str, Any]:
    """The ``info`` of a video feature as the installed LeRobot's writer records it in ``info.json``.

    0.4: ``get_video_info(path)`` = the stream's values plus ``video.is_depth_map: false``; 0.4 records no encoder settings,
    so ``video.g`` is added when ``gop`` is not LeRobot's (absent means LeRobot's, which is how 0.6 reads it). From 0.5:
    ``get_video_info(path, video_encoder=...)`` = the stream's values, the encoder's settings (``video.g``, ``video.crf``,
    ``video.preset``, ...) and ``is_depth_map: false``.

    Args:
        video_path: an MP4 encoded with GOP ``gop``.
        gop: its keyframe interval.

    Returns:
        The ``info`` dict.
    """
    video_utils = lerobot_video_utils()
    encoder = _rgb_encoder(gop)
    if encoder is None:
        info = dict(video_utils.get_video_info(video_path))
        if int(gop) != LEROBOT_VIDEO_GOP:
            info["video.g"] = int(gop)
        return info
    return dict(video_utils.get_video_info(video_path, video_encoder=encoder))


#: the largest GOP taken from a dataset's info.json (FFmpeg's ``g`` is a C int; a hostile value must not reach it)
MAX_VIDEO_GOP = 100_000


def video_gop(info: Any) -> int:
    """The GOP a video feature was encoded with, from its ``info`` in ``info.json`` (absent, or not a sane
    keyframe interval: LeRobot's). The file is untrusted input.

    >>> video_gop({"video.g": 10}), video_gop(None), video_gop({"video.g": 2**40}), video_gop(["not", "a", "dict"])
    (10, 2, 2, 2)
    """
    value = info.get("video.g") if isinstance(info, Mapping) else None
    ok = isinstance(value, int) and not isinstance(value, bool) and 0 < value <= MAX_VIDEO_GOP
    return int(value) if ok else LEROBOT_VIDEO_GOP


def video_backend() -> str:
    """The LeRobot video decoding backend that works here: ``"torchcodec"`` if it loads, else ``"pyav"``.

    LeRobot 0.4's default (``get_safe_default_codec``) picks torchcodec whenever the package is installed,
    even when its FFmpeg libraries are missing and it cannot load (then every video read fails); 0.6's
    ``get_safe_default_video_backend`` tries to import it and falls back to pyav. This is 0.6's rule, on both.
    """
    if find_spec("torchcodec") is None:
        return "pyav"
    try:
        import torchcodec.decoders  # noqa: F401  (heavy: torchcodec and its FFmpeg; only asked here)
    except Exception:  # noqa: BLE001 - ImportError, OSError, RuntimeError: the FFmpeg libraries are missing
        return "pyav"
    return "torchcodec"


def lerobot_default_video_backend() -> str:
    """The backend the installed LeRobot decodes videos with when it is not told one (``LeRobotDataset(repo_id)``,
    ``lerobot-train`` without ``--dataset.video_backend``, ``lerobot-dataset-viz``): 0.4's ``get_safe_default_codec``,
    0.5+'s ``get_safe_default_video_backend``. Where it differs from :func:`video_backend`, a LeRobot user must name
    ``pyav`` (0.4 picks an installed torchcodec that cannot load)."""
    try:
        from lerobot.utils.import_utils import get_safe_default_video_backend as default  # heavy: lerobot (torch); lerobot >= 0.5
    except ImportError:
        from lerobot.datasets.video_utils import get_safe_default_codec as default  # heavy: lerobot (torch); lerobot 0.4
    return default()


# --- tests: the clients pointed at a loopback Hub ------------------------------------------------


def point_clients_at(
    endpoint: str,
    home: Path,
    *,
    offline: bool,
    lerobot_home: Path,
    datasets_cache: Path,
    patch: Callable[[Any, str, Any], None],
) -> None:
    """Point the clients already imported (huggingface_hub, lerobot, datasets) at ``endpoint`` and at folders under
    ``home``: the module constants they computed once at import, those other modules copied by value (``from
    .constants import X``), and the endpoint the module-level ``HfApi`` froze. For tests and the demo
    (:func:`hub_envs.testing.hub_environment`, which sets the environment variables first and undoes every patch).

    Args:
        endpoint: the Hub's URL.
        home: the ``HF_HOME`` (its ``hub/``, ``assets/``, ``xet/``, ``token`` inside).
        offline: the clients' offline mode.
        lerobot_home: LeRobot's ``HF_LEROBOT_HOME``.
        datasets_cache: the ``datasets`` cache.
        patch: ``patch(module, name, value)`` sets one attribute (and remembers the old value to restore).
    """
    xet_cache, token_path = str(home / "xet"), str(home / "token")
    hub_cache, assets_cache = str(home / "hub"), str(home / "assets")
    url_template = endpoint + "/{repo_id}/resolve/{revision}/{filename}"
    values = {
        "ENDPOINT": endpoint,
        "HUGGINGFACE_CO_URL_TEMPLATE": url_template,
        "HF_HOME": str(home),
        "hf_cache_home": str(home),
        "default_cache_path": hub_cache,
        "default_assets_cache_path": assets_cache,
        "HUGGINGFACE_HUB_CACHE": hub_cache,
        "HUGGINGFACE_ASSETS_CACHE": assets_cache,
        "HF_HUB_CACHE": hub_cache,
        "HF_ASSETS_CACHE": assets_cache,
        "default_xet_cache_path": xet_cache,
        "HF_XET_CACHE": xet_cache,
        "HF_TOKEN_PATH": token_path,
        "HF_STORED_TOKENS_PATH": str(home / "stored_tokens"),
        "HF_HUB_OFFLINE": bool(offline),
        "HF_HUB_DISABLE_TELEMETRY": True,
        "HF_HUB_DISABLE_XET": True,
    }
    for name, value in values.items():
        patch(constants, name, value)
    # Modules that copied constants by value at import (`from .constants import X`).
    for module_name, names in (
        ("huggingface_hub.file_download", ("HUGGINGFACE_CO_URL_TEMPLATE", "HUGGINGFACE_HUB_CACHE")),
        ("huggingface_hub.hf_api", ("ENDPOINT",)),
        ("huggingface_hub.utils._cache_manager", ("HF_HUB_CACHE",)),
        ("huggingface_hub.utils._cache_assets", ("HF_ASSETS_CACHE",)),
    ):
        module = sys.modules.get(module_name)
        for name in names:
            patch(module, name, values[name])
    # The module-level HfApi behind `huggingface_hub.upload_file` & co. froze its endpoint.
    hf_api = sys.modules.get("huggingface_hub.hf_api")
    if hf_api is not None and hasattr(hf_api, "api"):
        patch(hf_api.api, "endpoint", endpoint)

    lerobot_constants = sys.modules.get("lerobot.utils.constants")
    if lerobot_constants is not None:
        old_home = getattr(lerobot_constants, "HF_LEROBOT_HOME", None)
        old_calibration = getattr(lerobot_constants, "HF_LEROBOT_CALIBRATION", None)
        for name, module in list(sys.modules.items()):
            if not (name == "lerobot" or name.startswith("lerobot.")) or module is None:
                continue
            if old_home is not None and getattr(module, "HF_LEROBOT_HOME", None) == old_home:
                patch(module, "HF_LEROBOT_HOME", lerobot_home)
            if old_home is not None and getattr(module, "HF_LEROBOT_HUB_CACHE", None) == old_home / "hub":  # 0.5+
                patch(module, "HF_LEROBOT_HUB_CACHE", lerobot_home / "hub")
            if old_calibration is not None and getattr(module, "HF_LEROBOT_CALIBRATION", None) == old_calibration:
                patch(module, "HF_LEROBOT_CALIBRATION", lerobot_home / "calibration")
        patch(lerobot_constants, "default_cache_path", lerobot_home)

    datasets_config = sys.modules.get("datasets.config")
    if datasets_config is not None:
        ds_cache = datasets_cache
        for name, value in {
            "HF_ENDPOINT": endpoint,
            "HUB_DATASETS_URL": endpoint + "/datasets/{repo_id}/resolve/{revision}/{path}",
            "HF_CACHE_HOME": str(home),
            "HF_DATASETS_CACHE": ds_cache,
            "HF_MODULES_CACHE": home / "modules",
            "DOWNLOADED_DATASETS_PATH": ds_cache / "downloads",
            "EXTRACTED_DATASETS_PATH": ds_cache / "downloads" / "extracted",
            "HF_HUB_OFFLINE": bool(offline),
            "HF_DATASETS_OFFLINE": bool(offline),
        }.items():
            patch(datasets_config, name, value)


# --- stdlib ------------------------------------------------------------------------------------


def live_children() -> set[int]:
    """Pids of this process's live multiprocessing children (public API: ``active_children``)."""
    import multiprocessing  # heavy-ish: only where pools run

    return {p.pid for p in multiprocessing.active_children() if p.pid is not None}


def terminate_new_children(before: set[int]) -> None:
    """Terminate the multiprocessing children started since ``before``.

    A ``ProcessPoolExecutor`` abandoned mid-run (``shutdown(wait=False)``) keeps its workers busy until their current task
    ends; Python 3.14 has ``terminate_workers()`` for that, older ones no public handle on the workers, so the children
    that appeared since the pool was made are stopped instead.

    Args:
        before: :func:`live_children` before the pool was made.
    """
    import multiprocessing  # heavy-ish: only where pools run

    for proc in multiprocessing.active_children():
        if proc.pid not in before and proc.is_alive():
            proc.terminate()


PY_VERSION = sys.version_info[:2]
