"""The checks a load runs once the env is registered (the three-way feature check, the golden-rollout fingerprint,
the env processors), the key their cached verdict is stored under, and the requirements preflight before them."""

from __future__ import annotations

import hashlib
import json
import warnings
from collections.abc import Mapping
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Literal

from hub_envs.dataset.reader import read_info
from hub_envs.envcode.envconfig import config_differences, encode_config, instantiate_config, validate_config_class
from hub_envs.errors import (
    DatasetError,
    EnvCodeError,
    FingerprintMismatchError,
    HubEnvsError,
    InvalidRepoFormatError,
    IsolationUnavailableError,
)
from hub_envs.harness.features import FeatureReport, check_features
from hub_envs.isolation.options import IsolationOptions
from hub_envs.loading import check_cache
from hub_envs.loading.isolated import worker_versions
from hub_envs.loading.loaded import LoadedEnv
from hub_envs.loading.processor_specs import declarations_source, parse_declarations
from hub_envs.loading.source import Source
from hub_envs.repo.format import DATASET_DIR, Manifest

FingerprintPolicy = Literal["error", "warn", "off"]

#: What a cached verdict of an in-process load holds besides the checks: the config the code computes matched the
#: manifest's values (:func:`checked_config`) and those give the env exactly what the config does
#: (:func:`manifest_reproduces`), so a later load with the same key may take them from the manifest.
CONFIG_CHECKED = ("config", "the code's config matches the manifest")

#: The field of a cached verdict saying the env processors' check (:func:`check_processors`, its dry run included)
#: passed, for the declarations whose digest it holds (:func:`declarations_digest`): a later load with the same key and
#: the same declarations neither builds nor runs them, so it imports neither torch nor LeRobot for them.
PROCESSORS_CHECKED = "processors"


def _same(a: Any, b: Any) -> bool:
    """Equal, and of the same types all the way down (a tuple the code gives is not the list JSON gives back)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(v, b[k]) for k, v in a.items())
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def manifest_reproduces(config: Any, manifest: Manifest) -> bool:
    """Whether registering from the manifest's values (``gym_kwargs``, ``episode_length``) gives the env exactly the
    arguments ``config`` gives it: JSON keeps dicts, lists, strings, numbers and booleans as they are, and nothing else.

    Args:
        config: the config the code computed.
        manifest: the verified manifest.

    Returns:
        True when they are the same values of the same types.
    """
    recorded = manifest.config or {}
    return _same(recorded.get("gym_kwargs"), config.gym_kwargs) and _same(recorded.get("episode_length"), config.episode_length)


@dataclass
class CheckPlan:
    """What a load's checks will do: the key their verdict is cached under, and the verdict cached before (None: run
    them)."""

    use_cache: bool
    key: str = ""
    cached: dict | None = None


def preflight(
    src: Source,
    iso: IsolationOptions,
    *,
    check: bool,
    recheck: bool,
    steps: int,
    fingerprint: FingerprintPolicy,
    machine: Future,
) -> CheckPlan:
    """The requirements preflight, unless a cached verdict says this repo@sha passed every stage before with exactly
    these installed distributions.

    Args:
        src: the load's source.
        iso: the load's options (a venv worker brings its requirements itself: its checks are keyed once its venv is
            known, :func:`plan_for_worker`).
        check: the load runs its checks (else nothing is cached or looked up).
        recheck: ignore a cached verdict.
        steps, fingerprint: the checks' settings (part of the key).
        machine: a future of :func:`~hub_envs.loading.check_cache.machine_identity`, computed while the files download.

    Returns:
        The :class:`CheckPlan`.

    Raises:
        MissingRequirementsError: a requirement is not installed, or at another version (nothing is installed for you).
    """
    use_cache = check and src.local_folder is None and not (recheck or check_cache.recheck_forced())
    plan = CheckPlan(use_cache=use_cache)
    if iso.isolation != "venv":
        plan.key = checks_key(src.where, src.manifest, steps=steps, fingerprint=fingerprint, machine=machine.result())
        plan.cached = check_cache.lookup(plan.key) if use_cache else None
        if plan.cached is None:
            from hub_envs.repo.requirements import check_requirements  # heavy-ish: importlib.metadata, packaging

            check_requirements(src.manifest.requirements, repo=src.where)
    return plan


def plan_for_worker(
    plan: CheckPlan, src: Source, iso: IsolationOptions, *, steps: int, fingerprint: FingerprintPolicy, machine: Future
) -> CheckPlan:
    """A venv-isolated load's checks run with its venv's packages: its :class:`CheckPlan` keyed on them too.

    Args:
        plan: the plan :func:`preflight` made.
        src: the load's source.
        iso: the load's options once its venv is built (:func:`~hub_envs.loading.isolated.isolated_parts`).
        steps, fingerprint, machine: as for :func:`preflight`.

    Returns:
        ``plan`` for any other load; for a venv worker's, a plan keyed on its venv.
    """
    record = worker_versions(iso) if iso.isolation == "venv" else None
    if record is None:
        return plan
    worker = {**machine.result(), "worker_venv": check_cache.venv_identity(record["path"])}
    key = checks_key(src.where, src.manifest, steps=steps, fingerprint=fingerprint, machine=worker)
    return CheckPlan(plan.use_cache, key, check_cache.lookup(key) if plan.use_cache else None)


def config_check_cached(plan: CheckPlan) -> bool:
    """Whether ``plan``'s cached verdict says the config check (:func:`checked_config`) passed too (an isolated load's
    verdict does not: its parent never runs the config's code)."""
    return plan.cached is not None and plan.cached.get(CONFIG_CHECKED[0]) == CONFIG_CHECKED[1]


def record_config_check(plan: CheckPlan) -> None:
    """Add to ``plan``'s cached verdict that the config check passed (a verdict an isolated load stored, or one older
    than that record), so the next in-process load can take the config from the manifest."""
    if plan.cached is not None and not config_check_cached(plan):
        result = {k: v for k, v in plan.cached.items() if k not in ("key", "checked_at", "digest")}
        check_cache.store(plan.key, {**result, CONFIG_CHECKED[0]: CONFIG_CHECKED[1]})


def checked_config(config_class: type, manifest: Manifest, set_fields: Mapping[str, Any], where: str) -> Any:
    """The env's config (its defaults with ``set_fields``), refused when it is not what the manifest recorded.

    Args:
        config_class: the repo's EnvConfig subclass.
        manifest: the verified manifest (its recorded ``config`` values).
        set_fields: the fields to set (a published variant's, or a local folder's ``config=``).
        where: names the load in messages.

    Returns:
        The config instance.

    Raises:
        InvalidRepoFormatError: the code computes other values than the manifest records.
        ConfigError, EnvCodeError: the config class is not an EnvConfig, or refuses the fields.
    """
    validate_config_class(config_class, where=where)
    config = instantiate_config(config_class, where=where, overrides=set_fields)
    if manifest.config:
        diffs = config_differences(manifest.config, encode_config(config))
        if diffs:
            what = "the code's defaults" if not set_fields else f"what the code computes from {dict(set_fields)}"
            raise InvalidRepoFormatError(
                f"{where}: the manifest's config values differ from {what}:\n  "
                + "\n  ".join(diffs)
                + "\nRe-publish with push_env so the manifest matches the code."
            )
    return config


def declarations_digest(manifest: Manifest) -> str:
    """The identity of the env processors a manifest declares (what :data:`PROCESSORS_CHECKED` records).

    Args:
        manifest: the verified manifest.

    Returns:
        64 hex digits: sha256 of its ``processors`` as canonical JSON.
    """
    return hashlib.sha256(json.dumps(list(manifest.processors), sort_keys=True).encode()).hexdigest()


def processors_check_cached(plan: CheckPlan, manifest: Manifest) -> bool:
    """Whether ``plan``'s cached verdict says the env processors ``manifest`` declares passed their check, dry run
    included (a verdict stored before that check passed, or by a load that failed it, does not)."""
    return plan.cached is not None and plan.cached.get(PROCESSORS_CHECKED) == declarations_digest(manifest)


def record_processors_check(plan: CheckPlan, manifest: Manifest) -> None:
    """Add to the verdict stored under ``plan``'s key (by this load's checks, or cached before) that the env processors
    ``manifest`` declares passed their check; no verdict there (the other checks drifted under ``fingerprint="warn"``,
    a read-only home), nothing is recorded: the next load checks them again."""
    entry = check_cache.lookup(plan.key) if plan.key else None
    digest = declarations_digest(manifest)
    if entry is not None and entry.get(PROCESSORS_CHECKED) != digest:
        result = {k: v for k, v in entry.items() if k not in ("key", "checked_at", "digest")}
        check_cache.store(plan.key, {**result, PROCESSORS_CHECKED: digest})


def check_processors(loaded: LoadedEnv, *, dry: bool, where: str, plan: CheckPlan | None = None) -> None:
    """The env processors the repo declares: well formed, buildable, and (``dry``) run once on a live observation;
    skipped (torch and LeRobot's processors left unimported) when ``plan``'s cached verdict says they passed, their
    declarations refused by an isolated load whatever it says.

    Args:
        loaded: the registered env.
        dry: also run every step once.
        where: names the load in messages.
        plan: the load's :class:`CheckPlan` (None: no verdict is looked at or recorded); a pass with ``dry`` is
            recorded in the verdict stored under its key (:func:`record_processors_check`).

    Raises:
        ProcessorError: naming the malformed declaration or the failing step.
        IsolationUnavailableError: an isolated load whose repo declares processors from its own code.
    """
    if loaded.isolation is not None and loaded.isolation.isolated:
        specs = parse_declarations(list(loaded.manifest.processors), where=declarations_source(loaded))
        own = [sp.name for sp in specs if ":" in sp.entry_point]
        if own:
            raise IsolationUnavailableError(
                f"{where} declares env processors from its own code ({', '.join(own)}), which would run in this "
                f"process; isolation does not support those yet (built-in and LeRobot-registry steps work). "
                f"Load it with isolation='none'."
            )
    if dry and plan is not None and processors_check_cached(plan, loaded.manifest):
        return  # built when used: loaded.processors(), LeRobot's make_env_pre_post_processors
    from hub_envs.loading.processors import validate_for  # heavy: torch, lerobot's processors

    validate_for(loaded, dry=dry)  # ProcessorError names the malformed field
    if dry and plan is not None:
        record_processors_check(plan, loaded.manifest)


def checks_key(where: str, manifest: Manifest, *, steps: int, fingerprint: FingerprintPolicy, machine: dict | None = None) -> str:
    """The key a load's check verdict is cached under (:func:`hub_envs.loading.check_cache.check_key`).

    Args:
        where: ``user/name@<sha>``.
        manifest: the verified manifest (its content digest, requirements, check seed, recorded fingerprint).
        steps: the feature check's steps.
        fingerprint: the fingerprint policy.
        machine: what the checks run with (:func:`~hub_envs.loading.check_cache.machine_identity`, a venv worker's
            too); None: computed now.

    Returns:
        64 hex digits.
    """
    recorded = manifest.fingerprint
    return check_cache.check_key(
        machine=machine,
        owner=where,
        content_digest=manifest.content_digest,
        requirements=manifest.requirements,
        settings={
            "steps": steps,
            "seed": int(manifest.seeds.get("check", 0)),
            "fingerprint": fingerprint,
            "recorded": recorded.get("digest") if recorded else None,
        },
    )


def run_load_checks(
    loaded: LoadedEnv,
    *,
    fingerprint: FingerprintPolicy,
    steps: int,
    key: str,
    cached: dict | None,
    config_checked: bool = False,
) -> None:
    """The load checks: the three-way feature check (declared / live / dataset) and the golden-rollout fingerprint;
    a pass is cached under ``key``, a verdict cached before (``cached``) is reported instead of run.

    Args:
        loaded: the registered env.
        fingerprint: what a drifted fingerprint does: ``"error"``, ``"warn"`` (a warning) or ``"off"``.
        steps: the feature check's random-action steps.
        key: the verdict's cache key (:func:`checks_key`).
        cached: a verdict cached before, or None.
        config_checked: the load checked its config against the manifest (in-process): the stored verdict says so.

    Raises:
        DatasetError: the manifest lists a dataset whose ``meta/info.json`` cannot be read.
        EnvCodeError: making the env raised.
        FeatureMismatchError: declared, live and recorded features disagree.
        FingerprintMismatchError: the fingerprint drifted (``fingerprint="error"``).
    """
    where = f"{loaded.repo_id}@{loaded.revision}"
    recorded = loaded.manifest.fingerprint
    config_note = dict([CONFIG_CHECKED]) if config_checked else {}
    if cached is not None:
        loaded.report.features = FeatureReport.from_dict(cached["features"])
        venv = " in the same worker venv" if loaded.worker_venv is not None else ""
        loaded.report.fingerprint = (
            f"{cached['fingerprint']} (cached: passed on {cached['checked_at']} with the same packages{venv}; "
            f"recheck=True, or hub-envs load --recheck=true, runs the checks again)"
        )
        return
    dataset_features = None
    dataset_dir = loaded.manifest.dataset.get("path") if loaded.manifest.dataset else None
    if loaded.dataset_meta_root is not None or dataset_dir:  # meta/info.json: no data file is fetched
        try:
            info = read_info(loaded.path / (dataset_dir or DATASET_DIR))
        except DatasetError as e:
            raise DatasetError(f"{where}: the manifest lists a dataset, but {e} Re-publish with push_env.") from e
        dataset_features = info.get("features", {})
    try:
        env = loaded.make()
    except HubEnvsError:
        raise
    except Exception as e:
        raise EnvCodeError(
            f"{where}: making the env ({loaded.manifest.env_entry_point} with its config's gym_kwargs) raised "
            f"{type(e).__name__}: {e}. Fix the env's __init__."
        ) from e
    handed_over = False  # the fingerprint's rollouts reuse this env (reset(seed) determines an episode) and close it
    try:
        report = check_features(
            loaded.config, env, dataset_features, steps=steps, seed=int(loaded.manifest.seeds.get("check", 0)), where=where
        )
        loaded.report.features = report
        report.raise_if_mismatch(where)
        if fingerprint == "off" or not recorded:
            loaded.report.fingerprint = "off" if fingerprint == "off" else "none recorded"
            check_cache.store(key, {"features": report.to_dict(), "fingerprint": loaded.report.fingerprint, **config_note})
            return

        from hub_envs.harness.checks import verify_fingerprint  # heavy: the rollout machinery (multiprocessing, tqdm)
        from hub_envs.harness.provenance import drift_note  # heavy-ish: importlib.metadata, packaging

        handed_over = True
        try:  # the versions are read only for the error message (milliseconds)
            verify_fingerprint(lambda: env, recorded, where=where, versions_note=lambda: drift_note(loaded))
            loaded.report.fingerprint = f"matches ({len(recorded['seeds'])} seeds x {recorded['steps']} steps)"
            check_cache.store(key, {"features": report.to_dict(), "fingerprint": loaded.report.fingerprint, **config_note})
        except FingerprintMismatchError as e:
            if fingerprint == "error":
                raise
            loaded.report.fingerprint = f"DRIFTED: {e}"
            warnings.warn(str(e), stacklevel=3)
    finally:
        if not handed_over:
            env.close()
