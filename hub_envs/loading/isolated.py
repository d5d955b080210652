"""How a load runs the env's code: the isolation keywords checked, what an isolated load registers (a factory of
proxies: this process never imports the env's code), its venv worker's record."""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypedDict

import gymnasium as gym

from hub_envs import errors
from hub_envs._text import safe_lines
from hub_envs.envcode.code_copy import code_files
from hub_envs.envcode.envconfig import instantiate_config, validate_config_class
from hub_envs.envcode.importing import import_env_folder, resolve_entry_point
from hub_envs.errors import ConfigError, InvalidRepoFormatError
from hub_envs.isolation.config import ManifestConfig
from hub_envs.isolation.options import IsolationOptions
from hub_envs.isolation.venvs import hub_envs_path, publisher_pins, venv_for, venv_python
from hub_envs.repo.format import Manifest


class CodeRun(TypedDict, total=False):
    """How an env's code runs: the keywords of :func:`hub_envs.load_env` that ``reproduce``, ``diff``, ``evaluate``
    and ``compare`` take as ``**run`` and pass on."""

    isolation: str
    sandbox: bool
    versions: str
    step_timeout: float | None


#: what :func:`hub_envs.load_env` does when a :class:`CodeRun` keyword is not given
CODE_RUN_DEFAULTS = CodeRun(isolation="none", sandbox=False, versions="current", step_timeout=None)


def code_run(run: Mapping[str, Any], where: str, *, complete: bool = False) -> CodeRun:
    """``run`` checked to hold only :class:`CodeRun` keywords: a misspelt one is named at once, not a ``TypeError``
    deep in ``load_env``.

    Args:
        run: the ``**run`` keywords an operation was given.
        where: the operation's name, for the message.
        complete: fill in the defaults of the keywords not given (a cache key).

    Returns:
        The keywords, as a :class:`CodeRun`.

    Raises:
        ConfigError: a keyword that is not one of :class:`CodeRun`'s.

    >>> code_run({"isolation": "process"}, "evaluate", complete=True)
    {'isolation': 'process', 'sandbox': False, 'versions': 'current', 'step_timeout': None}
    >>> code_run({"isolaton": "process"}, "evaluate")
    Traceback (most recent call last):
    ...
    hub_envs.errors.ConfigError: evaluate() got isolaton=: how an env's code runs is said with isolation, sandbox, versions, step_timeout (see hub_envs.load_env).
    """
    unknown = sorted(set(run) - set(CodeRun.__annotations__))
    if unknown:
        raise ConfigError(
            f"{where}() got {', '.join(k + '=' for k in unknown)}: how an env's code runs is said with "
            f"{', '.join(CodeRun.__annotations__)} (see hub_envs.load_env)."
        )
    return CodeRun(**{**(CODE_RUN_DEFAULTS if complete else {}), **run})


def isolation_options(
    isolation: str,
    sandbox: bool,
    versions: str,
    step_timeout: float | None,
    restart: bool,
    envs_per_worker: int,
    sandbox_limits: dict[str, int] | None = None,
) -> IsolationOptions:
    """load_env's isolation keywords, checked: every option either works or is refused with a typed error.

    Args:
        isolation, sandbox, versions, step_timeout, restart, envs_per_worker, sandbox_limits: as
            :func:`hub_envs.load_env` takes them.

    Returns:
        The :class:`~hub_envs.isolation.options.IsolationOptions` (``sandbox`` implies ``isolation="process"``).

    Raises:
        ConfigError: a value that is not an option, or options that do not go together.
        SandboxUnavailableError: a sandbox this machine cannot make (naming what it does not allow).
    """
    if isolation not in ("none", "process", "venv"):
        raise ConfigError(f"isolation={isolation!r} is not an isolation mode: pass 'none' (the default), 'process' or 'venv'.")
    if versions not in ("current", "publisher"):
        raise ConfigError(f"versions={versions!r}: pass 'current' (the default) or 'publisher'.")
    if versions == "publisher" and isolation != "venv":
        raise ConfigError(
            f"versions='publisher' runs the env in a venv of the publisher's package versions: pass isolation='venv' "
            f"with it (isolation={isolation!r} runs the packages installed here)."
        )
    if step_timeout is not None and not (isinstance(step_timeout, (int, float)) and step_timeout > 0):
        raise ConfigError(f"step_timeout={step_timeout!r}: pass a positive number of seconds (or None for no limit).")
    if not isinstance(envs_per_worker, int) or envs_per_worker < 0:
        raise ConfigError(f"envs_per_worker={envs_per_worker!r}: pass a positive number (or 0 for the default).")
    limits = dict(sandbox_limits or {})
    names = {"memory_mb": "memory_limit_mb", "open_files": "max_open_files", "processes": "max_processes"}
    bad = {k: v for k, v in limits.items() if k not in names or not isinstance(v, int) or v < 1}
    if bad:
        raise ConfigError(
            f"sandbox_limits={bad!r}: pass positive integers for any of {', '.join(names)} (e.g. {{'memory_mb': 2048}})."
        )
    if limits and not sandbox:
        raise ConfigError("sandbox_limits only apply with sandbox=True (a worker without the sandbox has no limits).")
    if sandbox:
        isolation = "process" if isolation == "none" else isolation
        from hub_envs.isolation.sandbox import require_sandbox  # heavy: the sandbox machinery (ctypes): only a sandboxed load

        require_sandbox(limits.get("memory_mb"))  # SandboxUnavailableError naming what this machine does not allow
    return IsolationOptions(
        isolation=isolation,
        sandbox=bool(sandbox),
        step_timeout=step_timeout,
        restart=bool(restart),
        envs_per_worker=envs_per_worker,
        versions=versions,
        **{names[k]: v for k, v in limits.items()},
    )


def isolation_suffix(iso: IsolationOptions) -> str:
    """What an isolated load's gym id and draccus name end with: the mode, and a digest of any non-default setting
    (two loads of one repo@sha with other settings are two registrations, never a conflict).

    Args:
        iso: an isolated load's options.

    Returns:
        ``-process``, ``-venv``, ``-sandbox``... (``-<mode>-<digest8>`` with settings of its own).
    """
    mode = iso.isolation + ("-sandbox" if iso.sandbox else "")
    mode = "sandbox" if mode == "process-sandbox" else mode
    settings = {f.name: getattr(iso, f.name) for f in dataclasses.fields(iso) if f.name not in ("python", "pythonpath")}
    default = dataclasses.asdict(IsolationOptions(isolation=iso.isolation, sandbox=iso.sandbox))
    if any(default[k] != v for k, v in settings.items()):
        mode += "-" + hashlib.sha256(repr(sorted(settings.items())).encode()).hexdigest()[:8]
    return f"-{mode}"


def isolated_parts(
    repo: str,
    sha: str,
    path: Path,
    key: str,
    manifest: Manifest,
    local_folder: Path | None,
    iso: IsolationOptions,
    overrides: Mapping[str, Any] | None = None,
) -> tuple[Any, type | None, Any]:
    """What an isolated load registers, without importing the env's code here: a factory of proxies as the gym entry
    point, and the config from the verified manifest (a local folder's, which is your own code, is imported).

    Args:
        repo, sha: the repo and commit.
        path: the folder the env's code is imported from (in the workers).
        key: the module key of repo@sha (:func:`hub_envs.envcode.importing.module_key`).
        manifest: the verified manifest.
        local_folder: the env folder of a local load (None: a Hub snapshot).
        iso: the load's options; ``isolation="venv"`` builds (or reuses) the worker's venv here.
        overrides: a local folder's config fields to set.

    Returns:
        ``(entry point, config class or None, config)``; the entry point's ``options`` are the load's, with the
        venv's python for ``isolation="venv"``.

    Raises:
        InvalidRepoFormatError: a Hub repo whose manifest records no config values.
        VenvBuildError: the worker's venv cannot be built.
    """
    from hub_envs.isolation.proxy import (  # heavy: the worker machinery (msgpack): only an isolated load
        EnvTarget,
        IsolatedEnvFactory,
    )

    where = f"{repo}@{sha}"
    config_class = None
    if manifest.config:
        config = ManifestConfig(manifest.config, where=f"{where}: hub_env.json")
    elif local_folder is not None:
        package = import_env_folder(path, key)
        config_class = resolve_entry_point(package, manifest.config_entry_point, where=f"{where}: config entry point")
        validate_config_class(config_class, where=where)
        config = instantiate_config(config_class, where=where, overrides=overrides or None)
    else:
        raise InvalidRepoFormatError(
            f"{where}: the manifest records no config values, which an isolated load reads instead of importing the "
            f"env's code. Re-publish with push_env."
        )
    if iso.isolation == "venv":
        notes: list[str] = []
        if iso.versions == "publisher":
            reqs, constraints, python, minor, notes = publisher_pins(
                manifest.requirements, dict(manifest.versions), dict(manifest.resolved), where=where
            )
            venv, record = venv_for(
                reqs, where=where, python=python, minor=minor, constraints=constraints, wheels_only=iso.sandbox
            )
        else:  # a sandboxed env's venv holds wheels only: building a package runs its code, outside the sandbox
            venv, record = venv_for(manifest.requirements, where=where, wheels_only=iso.sandbox)
        iso = dataclasses.replace(iso, python=str(venv_python(venv)), pythonpath=hub_envs_path())
        _VENVS[iso] = {**record, "path": str(venv), "notes": notes}
    target = EnvTarget(
        repo_id=repo,
        revision=sha,
        path=Path(path),
        key=key,
        entry_point=manifest.env_entry_point,
        files=tuple(sorted(code_files(manifest.files).items())),  # what ``path`` (the code copy) holds
        requirements=tuple(manifest.requirements),
    )
    factory = _FACTORIES.setdefault((target, iso), IsolatedEnvFactory(target, iso))  # one entry point per load setting
    return factory, config_class, config


#: What each venv worker setting runs: the venv's record (python, installed packages) and notes.
_VENVS: dict[Any, dict] = {}


def worker_versions(isolation: IsolationOptions | None) -> dict[str, Any] | None:
    """The venv record of a load's workers.

    Args:
        isolation: a load's options (None: in-process).

    Returns:
        For ``isolation="venv"``: the worker's venv record (``path``, ``python``, ``installed``, ``notes``); else None.
    """
    return _VENVS.get(isolation) if isolation is not None else None


#: The gym entry point of each isolated repo@sha and setting (load_env's registration is idempotent per entry point).
_FACTORIES: dict[Any, Any] = {}


def config_in_worker(gym_id: str, isolation: IsolationOptions, entry_point: str, fields: Mapping[str, Any], *, where: str) -> Any:
    """An isolated env's config with ``fields`` set, computed by the repo's config class in a worker (this process
    never imports the repo's code).

    Args:
        gym_id: the load's gym id (its entry point is the proxies' factory).
        isolation: the load's options.
        entry_point: the manifest's config entry point.
        fields: the fields to set before the config's ``__post_init__``.
        where: names the load in messages.

    Returns:
        A read-only :class:`~hub_envs.isolation.config.ManifestConfig` of what the config computed.

    Raises:
        HubEnvsError: the error the worker reported (:class:`~hub_envs.errors.ConfigError` for an unknown field,
            :class:`~hub_envs.errors.EnvCodeError` for what the env's code raised).
    """
    from hub_envs.isolation.proxy import Worker  # heavy: the worker machinery (msgpack): only an isolated load

    worker = Worker(gym.spec(gym_id).entry_point.target, isolation)
    try:
        answer = worker.request("config", entry_point, dict(fields), timeout=isolation.start_timeout)
    finally:
        worker.close()
    if "error" in answer:
        name, message = answer["error"]
        error = getattr(errors, name, None)
        if not (isinstance(error, type) and issubclass(error, errors.HubEnvsError)):
            error = errors.EnvCodeError
        raise error(safe_lines(message))  # text from the env's code: escaped
    return ManifestConfig(answer["values"], where=f"{where}: its config with {sorted(fields)}")


def describe_in_worker(gym_id: str, isolation: IsolationOptions, entry_point: str) -> Any:
    """What a function of an isolated env's code returns, called in a worker (this process never imports the code).

    Args:
        gym_id: the load's gym id (its entry point is the proxies' factory).
        isolation: the load's options.
        entry_point: ``module:function`` of the env's code, taking no argument; it returns what the wire carries.

    Returns:
        Its answer.

    Raises:
        RemoteEnvError: the function raised (the message is the worker's).
    """
    from hub_envs.isolation.proxy import Worker  # heavy: the worker machinery (msgpack): only an isolated load

    worker = Worker(gym.spec(gym_id).entry_point.target, isolation)
    try:
        return worker.request("describe", entry_point, timeout=isolation.start_timeout)
    finally:
        worker.close()


def isolated_vector_env(gym_id: str, isolation: IsolationOptions, n_envs: int, kwargs: Mapping[str, Any]) -> Any:
    """An isolated load's vector env: its envs in worker processes that step side by side.

    Args:
        gym_id: the load's gym id.
        isolation: the load's options.
        n_envs: how many envs.
        kwargs: ``gym.make`` keywords over the registered ones (``max_episode_steps`` included).

    Returns:
        An :class:`~hub_envs.isolation.vector.IsolatedVectorEnv`.
    """
    from hub_envs.isolation.vector import IsolatedVectorEnv  # heavy: the worker machinery (msgpack): only an isolated load

    spec = gym.spec(gym_id)
    kwargs = {**spec.kwargs, **kwargs}
    max_steps = kwargs.pop("max_episode_steps", spec.max_episode_steps)
    return IsolatedVectorEnv(
        spec.entry_point.target,
        isolation,
        n_envs,
        gym_id=gym_id,
        kwargs=kwargs,
        max_episode_steps=max_steps,
        disable_env_checker=spec.disable_env_checker,
    )
