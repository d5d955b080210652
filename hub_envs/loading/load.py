"""``load_env``: an env repo id in, a verified, trusted, registered and checked environment out, as a pipeline of the
stages in :mod:`~hub_envs.loading.source`, :mod:`~hub_envs.loading.checks` and :mod:`~hub_envs.loading.isolated`."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hub_envs._compat import lerobot_env_configs_imported
from hub_envs.envcode import registration
from hub_envs.envcode.code_copy import code_copy
from hub_envs.envcode.envconfig import validate_config_class
from hub_envs.envcode.importing import forget_env_folder, import_env_folder, is_imported, module_key, resolve_entry_point
from hub_envs.errors import ConfigError, InvalidRepoFormatError, RegistrationConflictError
from hub_envs.isolation.config import ManifestConfig
from hub_envs.isolation.options import IsolationOptions
from hub_envs.loading import check_cache
from hub_envs.loading.checks import (
    CheckPlan,
    FingerprintPolicy,
    check_processors,
    checked_config,
    config_check_cached,
    manifest_reproduces,
    plan_for_worker,
    preflight,
    record_config_check,
    run_load_checks,
)
from hub_envs.loading.isolated import isolated_parts, isolation_options, isolation_suffix
from hub_envs.loading.loaded import LoadedEnv, LoadReport, remember
from hub_envs.loading.plain import has_entry_path, is_plain_snapshot_error, load_plain, parse_hub_path
from hub_envs.loading.source import Source, finish_fetch, resolve_source
from hub_envs.repo.trust_list import DIGEST_RE

_log = logging.getLogger(__name__)


def load_env(
    repo_id: str,
    *,
    revision: str | None = None,
    trust_remote_code: bool = False,
    check: bool = True,
    fingerprint: FingerprintPolicy = "error",
    check_steps: int = 8,
    recheck: bool = False,
    token: str | None = None,
    cache_dir: str | Path | None = None,
    config: Mapping[str, Any] | None = None,
    isolation: str = "none",
    sandbox: bool = False,
    versions: str = "current",
    step_timeout: float | None = None,
    restart: bool = False,
    envs_per_worker: int = 0,
    sandbox_limits: dict[str, int] | None = None,
    content_digest: str | None = None,
) -> LoadedEnv:
    """Load an env repo by id (``"user/name"``, ``"user/name@rev"``) or from a local folder; a plain LeRobot EnvHub repo
    (no ``hub_env.json``; ``"user/name[@rev][:path]"`` as LeRobot's ``make_env`` names it) loads through
    :func:`hub_envs.loading.plain.load_plain`, with the same consent, pinning and isolation, and a warning and
    ``missing_guarantees`` naming what it cannot give (no manifest digest, no dataset, no fingerprint).

    The stages, in order: resolve, verify and trust (:func:`_resolve_source`), requirements, import (from
    :func:`hub_envs.envcode.code_copy.code_copy`) and register with the config checked against the manifest
    (:func:`_checked_config`), then the load checks and the env processors (:func:`_check_processors`).

    Args:
        repo_id: a Hub repo id, optionally ``@revision``, or the path of a local env folder.
        revision: a branch, tag or 40-hex commit sha (overrides ``@rev``). Pin a sha for reproducibility.
        trust_remote_code: consent to import and run the repo's code for this call. Without it, the
            repo@sha must be in the trust list (``hub-envs trust user/name@sha``). Local folders are yours.
        check: run the three-way feature check and the fingerprint check after registering.
        fingerprint: what a drifted golden-rollout fingerprint does: ``"error"``, ``"warn"`` or ``"off"``.
        check_steps: random-action steps of the feature check.
        recheck: run the checks even if they already passed for this repo@sha with the same packages
            and platform (a venv worker's: those of its venv; see :mod:`hub_envs.loading.check_cache`;
            ``hub-envs load --recheck=true`` and ``HUB_ENVS_RECHECK=1`` do the same).
        token: the Hub token to download with (None: huggingface_hub's own: ``HF_TOKEN``, ``hf auth login``).
        cache_dir: the Hugging Face cache to download into (None: the default, ``$HF_HUB_CACHE``).
        config: for a local folder, config fields to set (``{"obs_type": "pixels_agent_pos"}``; values are
            decoded as LeRobot's ``--env.<field>=<value>`` flags are), the variant ``push_env --config.*``
            publishes. A Hub repo's config is the one it published (its own variant included).
        isolation: ``"none"`` (the env's code runs in this process), ``"process"`` (each env, or each group of
            ``envs_per_worker`` envs of ``make_vec``, runs in a worker process; this process never imports the
            env's code) or ``"venv"`` (the same, with the worker in a venv built with uv from the env's
            requirements, cached under ``$HUB_ENVS_HOME/venvs``). See :mod:`hub_envs.isolation`.
        sandbox: run the workers in a sandbox (implies ``isolation="process"``): no network, a read-only view
            of the files, no secrets in the environment, resource limits; fails closed where the machine does
            not allow a part of it (:class:`~hub_envs.errors.SandboxUnavailableError`).
        versions: ``"current"`` (the packages installed here); ``"publisher"`` (with ``isolation="venv"``): the
            venv pins the versions the publisher recorded.
        step_timeout: seconds a call into an isolated env may take before its worker is killed
            (:class:`~hub_envs.errors.EnvTimeoutError`); None: no limit (a sandbox: 60 s).
        restart: with isolation, ``reset()`` after a crash or timeout starts a fresh worker.
        envs_per_worker: with isolation, envs of one ``make_vec`` per worker process (0: spread over all CPUs but
            one; with fewer workers than CPUs both sides busy-wait, see :mod:`hub_envs.isolation.vector`).
        sandbox_limits: the sandbox's resource limits, any of ``memory_mb`` (default 4096: all its processes
            together, by a memory cgroup; asked for where none can be made, it is refused; the default then holds
            each process alone), ``open_files`` (256, per process) and ``processes`` (64, threads included, counted
            for the sandbox's uid).
        content_digest: the manifest content digest (64 hex, ``loaded.manifest.content_digest``) the load must find: a
            commit holding other content is refused with :class:`~hub_envs.errors.UntrustedCodeError` before anything
            of it is imported. A Ray worker gets the driver's, so consent given on the driver covers only that content.

    Returns:
        A :class:`LoadedEnv`.

    Raises:
        ConfigError: an argument that is not an option (a policy, an isolation mode, a digest...).
        EnvRepoNotFoundError, RevisionNotFoundError: no such repo or revision (``OfflineNotCachedError`` offline).
        IntegrityError: a file differs from the manifest, or a content tag names other content.
        UntrustedCodeError: no consent to run this commit's code (``trust_remote_code=True`` or ``hub-envs trust``).
        MissingRequirementsError: a requirement is not installed (nothing is installed for you).
        RegistrationConflictError, EnvCodeError: the code registers names of its own, or raises on import.
        FeatureMismatchError, FingerprintMismatchError: a load check failed.
        SandboxUnavailableError, IsolationUnavailableError: the isolation asked for cannot be made here.

    All are :class:`~hub_envs.errors.HubEnvsError` s whose message says what to do next.

    Example:
        >>> import gymnasium as gym
        >>> from hub_envs import load_env
        >>> env = load_env("user/pendulum-lerobot@<sha>", trust_remote_code=True)   # doctest: +SKIP
        >>> obs, info = gym.make(env.gym_id).reset(seed=0)                          # doctest: +SKIP
    """
    _check_arguments(repo_id, fingerprint, content_digest)
    iso = isolation_options(isolation, sandbox, versions, step_timeout, restart, envs_per_worker, sandbox_limits)
    if has_entry_path(repo_id):  # LeRobot's user/name[@rev]:path: an entry file of a plain EnvHub repo
        if not str(repo_id).endswith(":env.py"):
            return _load_plain(
                repo_id, revision, trust_remote_code, check, token, cache_dir, config, iso, versions, content_digest
            )
        repo_id = str(repo_id).removesuffix(":env.py")  # LeRobot's name of any repo's env.py: a published one's too
    report, timings, t0 = LoadReport(), {}, time.perf_counter()
    machine = _in_background(check_cache.machine_identity)  # what the check cache keys on, while the files download
    try:
        src = resolve_source(
            repo_id,
            revision=revision,
            trust_remote_code=trust_remote_code,
            config=config,
            token=token,
            cache_dir=cache_dir,
            report=report,
            content_digest=content_digest,
        )
    except InvalidRepoFormatError as e:
        if not is_plain_snapshot_error(e):
            raise
        return _load_plain(
            str(repo_id), revision, trust_remote_code, check, token, cache_dir, config, iso, versions, content_digest
        )
    timings["fetch_verify"] = time.perf_counter() - t0
    try:
        t = time.perf_counter()
        plan = preflight(src, iso, check=check, recheck=recheck, steps=check_steps, fingerprint=fingerprint, machine=machine)
        report.requirements = list(src.manifest.requirements)
        timings["requirements"] = time.perf_counter() - t
        loaded = _register_and_check(
            src,
            iso,
            plan,
            _Run(config, check, check_steps, fingerprint, machine, report, timings, token, cache_dir),
        )
    except BaseException:
        src.cancel()  # nothing of a failed load keeps downloading
        raise
    timings["total"] = time.perf_counter() - t0
    report.timings = timings
    remember(loaded)
    return loaded


def _load_plain(
    repo_id: str, revision, trust_remote_code, check, token, cache_dir, config, iso, versions, content_digest=None
) -> LoadedEnv:
    """A plain LeRobot EnvHub repo: what it cannot take refused, then :func:`~hub_envs.loading.plain.load_plain`."""
    ref = parse_hub_path(repo_id)
    if revision is not None:
        ref = dataclasses.replace(ref, revision=revision)
    if config:
        raise ConfigError(f"load_env({repo_id!r}, config=...): a plain EnvHub repo's make_env takes no config fields.")
    if versions != "current":
        raise ConfigError(f"{repo_id}: versions={versions!r} needs the versions a publisher recorded; a plain repo records none.")
    return load_plain(
        ref,
        trust_remote_code=trust_remote_code,
        check=check,
        token=token,
        cache_dir=cache_dir,
        iso=iso,
        content_digest=content_digest,  # a Ray worker's binding to the driver's consent holds for plain repos too
        stacklevel=4,
    )


def _check_arguments(repo_id: Any, fingerprint: str, content_digest: Any) -> None:
    """Refuse, before anything is fetched, what ``load_env`` cannot take (a :class:`ConfigError` naming it)."""
    if fingerprint not in ("error", "warn", "off"):
        raise ConfigError(f"fingerprint={fingerprint!r} is not a policy: pass 'error' (the default), 'warn' or 'off'.")
    if content_digest is not None and not (isinstance(content_digest, str) and DIGEST_RE.fullmatch(content_digest)):
        raise ConfigError(f"content_digest={content_digest!r}: pass a manifest's content digest (64 lowercase hex digits).")
    if not isinstance(repo_id, (str, os.PathLike)) or not str(repo_id).strip():
        raise ConfigError(
            f"load_env needs a Hub repo id such as 'user/name' or 'user/name@<sha>', or an env folder; got {repo_id!r}."
        )


@dataclass(frozen=True)
class _Run:
    """What the registration stage needs of ``load_env``'s call."""

    config: Mapping[str, Any] | None
    check: bool
    check_steps: int
    fingerprint: FingerprintPolicy
    machine: concurrent.futures.Future
    report: LoadReport
    timings: dict[str, float]
    token: str | None
    cache_dir: str | Path | None


@dataclass(frozen=True)
class _Parts:
    """What a load registers: the gym entry point (the env class, or a factory of isolated proxies), the config class
    (None when isolated without it here, or not imported yet) and the config, the options of an isolated load's
    workers, and what imports the config class when it is first asked for (:class:`_DeferredConfig`)."""

    env_class: Any
    config_class: type | None
    config: Any
    iso: IsolationOptions
    deferred: _DeferredConfig | None = None


class _DeferredConfig:
    """The config class and config of an in-process load whose checks passed before, the config module (and LeRobot,
    which it imports) imported on first use: the env's gym registration needs only the manifest's values
    (:class:`~hub_envs.isolation.config.ManifestConfig`), which the cached verdict says the code computes."""

    def __init__(self, src: Source, code: Path, key: str, set_fields: Mapping[str, Any]):
        self._src, self._code, self._key, self._set_fields = src, code, key, dict(set_fields)
        self._class: type | None = None

    def config_class(self) -> type:
        """The repo's EnvConfig subclass, imported now (once).

        Raises:
            InvalidRepoFormatError, EnvCodeError, RegistrationConflictError: as an in-process ``load_env`` would.
        """
        if self._class is None:
            import lerobot.envs  # noqa: F401  (heavy: lerobot, torch; first, so the choices waiting for it register before)

            src = self._src
            package = import_env_folder(self._code, self._key)
            config_class = resolve_entry_point(package, src.manifest.config_entry_point, where=f"{src.where}: config entry point")
            validate_config_class(config_class, where=src.where)
            self._class = config_class
        return self._class

    def config(self) -> Any:
        """The config the code computes, checked against the manifest's values (as an in-process ``load_env`` checks it).

        Raises:
            InvalidRepoFormatError: the code computes other values than the manifest records.
        """
        return checked_config(self.config_class(), self._src.manifest, self._set_fields, self._src.where)


def _register_and_check(src: Source, iso: IsolationOptions, plan: CheckPlan, run: _Run) -> LoadedEnv:
    """Import the code (or, isolated, build the proxies' factory), register it with gymnasium and draccus, run the
    checks and wait for the rest of the files: in one registry transaction, so a failure leaves the registries as
    they were, and nothing of a failed first load stays imported."""
    key = module_key(src.repo, src.sha)
    imported_before = is_imported(key)  # an earlier successful load of this repo@sha keeps its modules
    try:
        t = time.perf_counter()
        # a published env's code runs from real files (its own folder for __file__.resolve()), not cache symlinks
        code = src.path if src.local_folder is not None else code_copy(src.path, src.manifest.files, src.repo, src.sha)
        set_fields = src.manifest.config_overrides if src.local_folder is None else dict(run.config or {})
        with registration.registry_transaction() as txn:
            deferred = _DeferredConfig(src, code, key, set_fields) if _config_can_wait(src, iso, plan) else None
            parts = _import_parts(src, code, key, iso, run.config, deferred=deferred)
            _refuse_replacements(txn, code, src.where)
            if not iso.isolated and parts.deferred is None:  # the config the code computes, checked against the manifest's
                config = checked_config(parts.config_class, src.manifest, set_fields, src.where)
                parts = dataclasses.replace(parts, config=config)
                if manifest_reproduces(config, src.manifest):  # the next load may register from the manifest alone
                    record_config_check(plan)
            reg = _register(src, parts)
            run.timings["import_register"] = time.perf_counter() - t
            loaded = LoadedEnv(
                repo_id=src.repo,
                revision=src.sha,
                requested_revision=src.requested,
                path=src.path,
                manifest=src.manifest,
                env_class=parts.env_class,
                config_class=parts.config_class,
                config=parts.config if parts.deferred is None else None,  # deferred: the real one, when asked for
                registration=reg,
                report=run.report,
                local_folder=src.local_folder,
                isolation=parts.iso,
                token=run.token,
                cache_dir=run.cache_dir,
                deferred_config=parts.deferred,
            )
            if run.check:
                t = time.perf_counter()
                plan = plan_for_worker(
                    plan, src, parts.iso, steps=run.check_steps, fingerprint=run.fingerprint, machine=run.machine
                )
                run_load_checks(
                    loaded,
                    fingerprint=run.fingerprint,
                    steps=run.check_steps,
                    key=plan.key,
                    cached=plan.cached,
                    config_checked=not iso.isolated and manifest_reproduces(parts.config, src.manifest),
                )
                run.timings["checks"] = time.perf_counter() - t
            if src.manifest.processors:
                check_processors(loaded, dry=run.check, where=src.where, plan=plan if run.check else None)
            t = time.perf_counter()
            finish_fetch(src, token=run.token, cache_dir=run.cache_dir)  # the card and meta/, downloaded meanwhile
            run.timings["fetch_rest"] = time.perf_counter() - t
    except BaseException:
        if not imported_before and not iso.isolated:
            forget_env_folder(key)
        raise
    return loaded


def _config_can_wait(src: Source, iso: IsolationOptions, plan: CheckPlan) -> bool:
    """Whether an in-process load may leave the config's module (and LeRobot, which it imports) unimported until the
    config is asked for: a Hub repo whose manifest records the config's values, whose checks passed before with these
    very packages, the config check against the manifest included (the cached verdict says so), while LeRobot's config
    system is not imported here (when it is, the config class is cheap to import and its choice is wanted now)."""
    return (
        not iso.isolated
        and src.local_folder is None
        and bool(src.manifest.config)
        and config_check_cached(plan)
        and not lerobot_env_configs_imported()
    )


def _import_parts(
    src: Source,
    code: Path,
    key: str,
    iso: IsolationOptions,
    config: Mapping[str, Any] | None,
    *,
    deferred: _DeferredConfig | None = None,
) -> _Parts:
    """Import the env's entry points here, or (isolated) build the proxies' factory, the config read from the manifest;
    with ``deferred``, the env's entry point only, the config's values from the manifest."""
    if iso.isolated:
        factory, config_class, isolated_config = isolated_parts(
            src.repo, src.sha, code, key, src.manifest, src.local_folder, iso, overrides=dict(config or {})
        )
        return _Parts(factory, config_class, isolated_config, factory.options)
    package = import_env_folder(code, key)
    env_class = resolve_entry_point(package, src.manifest.env_entry_point, where=f"{src.where}: env entry point")
    if deferred is not None:
        return _Parts(env_class, None, ManifestConfig(src.manifest.config, where=f"{src.where}: hub_env.json"), iso, deferred)
    config_class = resolve_entry_point(package, src.manifest.config_entry_point, where=f"{src.where}: config entry point")
    return _Parts(env_class, config_class, None, iso)  # the config: once no replaced registration is in the way


def _refuse_replacements(txn: Any, code: Path, where: str) -> None:
    """The env's code may not replace an entry another package registered with one of its own."""
    replaced, by_packages = txn.replaced_by(code)
    if replaced:
        raise RegistrationConflictError(
            f"{where}: its code replaced {', '.join(replaced)}, already registered by another package, with "
            f"an entry of its own. Remove the env code's own gym.register / @EnvConfig.register_subclass calls: "
            f"hub-envs registers the env itself, under names unique to the repo and commit."
        )
    for distribution, names in by_packages.items():  # what importing that package does in any process
        _log.info("%s: importing %s re-registered %s", where, distribution, ", ".join(names))


def _register(src: Source, parts: _Parts) -> registration.Registration:
    """Register with gymnasium and draccus under names unique to repo@sha (and to an isolated load's settings)."""
    iso, config = parts.iso, parts.config
    qualifier = src.sha[:12] if not src.sha.startswith("local-") else src.sha
    suffix = isolation_suffix(iso) if iso.isolated else ""
    return registration.register(
        gym_id=f"{src.manifest.gym_id}-{qualifier.replace('local-', 'local')}{suffix}",
        env_type=f"{src.manifest.env_type}@{qualifier}{suffix}",
        owner=f"{src.where} ({suffix.lstrip('-')})" if iso.isolated else src.where,  # not the in-process registration
        entry_point=parts.env_class,
        config_class=parts.deferred.config_class if parts.deferred is not None else parts.config_class,
        max_episode_steps=int(config.episode_length),
        kwargs=config.gym_kwargs,
        disable_env_checker=bool(getattr(config, "disable_env_checker", True)),
        register_choice=not iso.isolated or parts.config_class is not None,  # in-process: always, deferred or not
    )


def _in_background(fn: Callable[[], Any]) -> concurrent.futures.Future:
    """``fn()`` in a daemon thread of its own; its result (or exception) in the returned future."""
    future: concurrent.futures.Future = concurrent.futures.Future()

    def run() -> None:
        try:
            future.set_result(fn())
        except BaseException as e:  # noqa: BLE001 - handed to whoever asks for the result
            future.set_exception(e)

    threading.Thread(target=run, name="hub-envs-load-identity", daemon=True).start()
    return future
