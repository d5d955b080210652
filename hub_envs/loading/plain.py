"""``load_env`` of a plain LeRobot EnvHub repo (no ``hub_env.json``: an entry file with ``make_env(n_envs,
use_async_envs, cfg=None)`` and a ``requirements.txt``), by ``user/name[@rev][:path]`` as LeRobot's ``make_env`` names
it: the same consent, trust-on-first-use, pinning, requirements preflight and isolation as a published repo, and a
:class:`~hub_envs.loading.loaded.LoadedEnv` that says which guarantees it cannot give (:data:`MISSING_GUARANTEES`)."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import shutil
import sys
import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym

from hub_envs._text import safe_text
from hub_envs.envcode import registration
from hub_envs.envcode.envconfig import encode_config, instantiate_config, validate_config_class
from hub_envs.envcode.importing import forget_env_folder, import_env_folder, is_imported, module_key, resolve_entry_point
from hub_envs.errors import (
    ConfigError,
    EnvCodeError,
    EnvContractError,
    HubEnvsError,
    IntegrityError,
    InvalidRepoFormatError,
    ManifestError,
    PlainRepoWarning,
    RegistrationConflictError,
    UnpinnedRevisionWarning,
    UntrustedCodeError,
)
from hub_envs.isolation.options import IsolationOptions
from hub_envs.loading.isolated import describe_in_worker, isolated_parts, isolation_suffix
from hub_envs.loading.loaded import LoadedEnv, LoadReport, remember
from hub_envs.loading.source import _check_content_digest, _trust_gate
from hub_envs.paths import PACKAGE_DIR, hub_envs_home
from hub_envs.repo import trust_list
from hub_envs.repo.format import (
    MANIFEST_FILE,
    SUITE_FORMAT_VERSION,
    Manifest,
    content_digest,
    hash_files,
    is_bytecode_path,
    safe_relpath,
)
from hub_envs.repo.refs import parse_repo_ref

#: The entry file LeRobot's ``make_env`` reads when the reference names none.
DEFAULT_ENTRY = "env.py"
#: The requirements file of LeRobot's EnvHub repos (LeRobot leaves installing it to the user).
REQUIREMENTS_FILE = "requirements.txt"
#: The adapter modules hub-envs writes next to the repo's files (``source/``): the env, and its LeRobot config.
ENV_MODULE, CONFIG_MODULE = "hub_envs_plain_env", "hub_envs_plain_config"
ENV_ENTRY_POINT, CONFIG_ENTRY_POINT = f"{ENV_MODULE}:PlainEnv", f"{CONFIG_MODULE}:PlainEnvConfig"
SOURCE_DIR = "source"
#: The episode length of a plain load's config (the env's own time limit, if any, ends episodes first).
DEFAULT_EPISODE_LENGTH = 1000

#: What a plain repo cannot give, as ``LoadedEnv.missing_guarantees`` and the load's warning list them.
MISSING_GUARANTEES = (
    "no manifest digest: the files are whatever the commit holds (consent binds their digest, computed here)",
    "no dataset: nothing recorded to check the env's features against",
    "no fingerprint: no golden rollout to detect drift across package versions",
    "no declared features: LeRobot's features are inferred, not published",
)


@dataclass(frozen=True)
class PlainRef:
    """A LeRobot EnvHub reference ``user/name[@rev][:path]``."""

    repo: str
    revision: str | None
    entry: str
    explicit_entry: bool

    def text(self, sha: str | None = None) -> str:
        """``user/name@<rev>[:path]`` as LeRobot's ``make_env`` takes it (``sha`` instead of the revision when given)."""
        rev = sha or self.revision
        return f"{self.repo}{'@' + rev if rev else ''}{':' + self.entry if self.explicit_entry else ''}"


def parse_hub_path(ref: str) -> PlainRef:
    """Split a LeRobot EnvHub reference as LeRobot's ``_parse_hub_url`` does: ``user/name[@rev][:path]``.

    Args:
        ref: the reference (``"user/name"``, ``"user/name@<sha>"``, ``"user/name@v1:envs/Task.py"``).

    Returns:
        The :class:`PlainRef` (entry ``env.py`` when no ``:path`` is given).

    Raises:
        ConfigError: not a repo id, or a path that is not a ``.py`` file inside the repo.
    """
    head, colon, entry = str(ref).partition(":")
    repo, revision = parse_repo_ref(head)
    if colon:
        try:
            entry = safe_relpath(entry, where=f"{safe_text(ref)}: the entry file")
        except HubEnvsError as e:
            raise ConfigError(str(e)) from None
        if not entry.endswith(".py"):
            raise ConfigError(f"{safe_text(ref)}: the entry file after ':' must be a .py file (e.g. 'user/name:envs/task.py').")
    return PlainRef(repo, revision, entry if colon else DEFAULT_ENTRY, bool(colon))


def has_entry_path(ref: Any) -> bool:
    """Whether ``ref`` is a Hub reference naming an entry file (``user/name[@rev]:path``), LeRobot's form for plain repos.

    Args:
        ref: what ``load_env`` was given.

    Returns:
        True for text with a ``:`` after a ``user/name`` part.
    """
    return isinstance(ref, str) and bool(re.fullmatch(r"[^/:@]+/[^/:@]+(@[^:]*)?:.+", ref, re.S))


# --- fetch -------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlainSource:
    """A plain repo at one commit, fetched through hub_io and hashed (nothing of it imported)."""

    ref: PlainRef
    sha: str
    path: Path
    files: dict[str, str]  # every file of the commit (but .gitattributes): sha256
    digest: str  # what consent binds: trust_list.snapshot_digest of the same files
    requirements: tuple[str, ...]
    requirement_notes: tuple[str, ...]

    @property
    def where(self) -> str:
        return f"{self.ref.repo}@{self.sha}"


def read_requirements(path: Path, *, where: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The requirements of a ``requirements.txt`` (PEP 508 lines; comments and blank lines skipped).

    Args:
        path: the file (it may not exist).
        where: names the repo in messages.

    Returns:
        ``(requirements, notes)``: the notes name the lines hub-envs cannot check (pip options such as ``-e``, ``-r``,
        ``--index-url``), which it leaves out.

    Raises:
        InvalidRepoFormatError: a line that is neither an option nor a valid requirement.
    """
    from packaging.requirements import InvalidRequirement, Requirement

    if not path.is_file():
        return (), ()
    reqs, notes = [], []
    for n, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        line = raw.split(" #", 1)[0].strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("-"):
            notes.append(f"{REQUIREMENTS_FILE}:{n} {safe_text(line)!r} is a pip option: not checked")
            continue
        try:
            Requirement(line)
        except InvalidRequirement as e:
            raise InvalidRepoFormatError(
                f"{where}: {REQUIREMENTS_FILE} line {n} ({safe_text(line)!r}) is not a valid requirement ({e}). "
                f"Fix the file, or ask the repo's author."
            ) from None
        reqs.append(line)
    return tuple(reqs), tuple(notes)


def fetch_plain(ref: PlainRef, *, token: str | None = None, cache_dir: str | Path | None = None) -> PlainSource:
    """Resolve and download a plain repo's commit through hub_io (the endpoint's answers checked as for any load),
    hash its files and read its requirements.

    Args:
        ref: the reference.
        token: as for :func:`hub_envs.load_env`.
        cache_dir: as for :func:`hub_envs.load_env`.

    Returns:
        The :class:`PlainSource`.

    Raises:
        EnvRepoNotFoundError, RevisionNotFoundError, OfflineNotCachedError, HostileResponseError: from hub_io.
        InvalidRepoFormatError: the entry file is not in the commit, it holds bytecode (``.pyc``, ``__pycache__/``), or
            ``requirements.txt`` is malformed.
        IntegrityError: the cached snapshot holds a link outside the cache's ``blobs/``, or a file the commit does not list.
    """
    from hub_envs.repo import hub_io  # heavy: huggingface_hub's client (load_env imports this module for every load)

    snap = hub_io.resolve_snapshot(ref.repo, ref.revision, token=token, cache_dir=cache_dir)
    path, where = snap.path, f"{ref.repo}@{snap.sha}"
    names = sorted(p.relative_to(path).as_posix() for p in path.rglob("*") if p.is_file() and p.name != ".gitattributes")
    for name in names:
        safe_relpath(name, where=where)
    # as for a hub-envs repo: every file a link into the cache's blobs/, none the commit does not list (when it was listed)
    try:
        hub_io.check_snapshot_layout(path, set(snap.fetched or names), where=where)
    except IntegrityError:
        hub_io.drop_snapshot(path)  # as for a hub-envs repo: what it held is not run later, by LeRobot's loader either
        raise
    bytecode = [safe_text(n) for n in names if is_bytecode_path(n)]
    if bytecode:  # the trust prompt lists .py files; Python would run the bytecode instead of the .py beside it
        raise InvalidRepoFormatError(
            f"{where}: holds compiled bytecode ({', '.join(bytecode[:8])}{' …' if len(bytecode) > 8 else ''}), which Python "
            f"runs instead of the .py source beside it (what you read before consenting). hub-envs loads .py sources only: "
            f"ask the repo's author to delete the __pycache__ folders and .pyc/.pyo files."
        )
    if ref.entry not in names:
        found = [safe_text(n) for n in names if n.endswith(".py")]
        raise InvalidRepoFormatError(
            f"{where}: the entry file {safe_text(ref.entry)} is not in the repo (its .py files: {', '.join(found) or 'none'}). "
            f"Name the file that defines make_env after ':' (user/name@rev:path/to/file.py)."
        )
    files = hash_files(path, names)
    reqs, notes = read_requirements(path / REQUIREMENTS_FILE, where=where)
    return PlainSource(ref, snap.sha, path, files, content_digest(files), reqs, notes)


# --- the code folder ---------------------------------------------------------------------------------------------------


def render_adapter(
    source: str,
    entry: str,
    *,
    features: dict | None = None,
    features_map: dict | None = None,
    task: str | None = None,
    fps: int = 30,
    episode_length: int = DEFAULT_EPISODE_LENGTH,
) -> dict[str, bytes]:
    """The two adapter modules for a plain repo's entry file (``hub_envs/templates/plain_env.py``, ``plain_config.py``).

    Args:
        source: ``user/name@<sha>:<entry>``, which the adapter names in its messages.
        entry: the entry file inside ``source/``.
        features, features_map: the config's LeRobot features (``{name: (FeatureType name, shape)}``) and their names.
        task, fps, episode_length: the config's defaults.

    Returns:
        ``{file name: content}``.
    """
    env_text = (PACKAGE_DIR / "templates" / "plain_env.py").read_text(encoding="utf-8")
    config_text = (PACKAGE_DIR / "templates" / "plain_config.py").read_text(encoding="utf-8")
    env_values = {'"{{SOURCE}}"': repr(source), '"{{SOURCE_ENTRY}}"': repr(entry)}
    config_values = {
        "{{FEATURES}}": repr({k: (t, list(s)) for k, (t, s) in (features or {}).items()}),
        "{{FEATURES_MAP}}": repr(dict(features_map or {})),
        "{{TASK}}": repr(task),
        "{{FPS}}": repr(int(fps)),
        "{{EPISODE_LENGTH}}": repr(int(episode_length)),
    }
    return {
        f"{ENV_MODULE}.py": _fill(env_text, env_values).encode(),
        f"{CONFIG_MODULE}.py": _fill(config_text, config_values).encode(),
    }


def _fill(template: str, values: dict[str, str]) -> str:
    """``template`` with each placeholder replaced in one pass: a value (an entry file's name, an env's task) that holds
    a placeholder's text is never read again as one (red-team finding, session 29: an entry file named
    ``x"{{SOURCE_ENTRY}}".py`` made the adapter's source, so code of the file name's choosing)."""
    return re.sub("|".join(re.escape(k) for k in sorted(values, key=len, reverse=True)), lambda m: values[m.group(0)], template)


def code_folder_files(src: PlainSource, adapter: dict[str, bytes]) -> dict[str, bytes]:
    """The files of a plain repo's code folder: the repo's own under ``source/``, the adapter at the top."""
    files = {f"{SOURCE_DIR}/{rel}": (src.path / rel).read_bytes() for rel in src.files}
    for rel, data in files.items():
        if hashlib.sha256(data).hexdigest() != src.files[rel.removeprefix(SOURCE_DIR + "/")]:
            raise InvalidRepoFormatError(f"{src.where}: {safe_text(rel)} changed in the cache since it was hashed; load again.")
    return {**files, **adapter}


def write_folder(target: Path, files: dict[str, bytes]) -> Path:
    """``target`` holding exactly ``files`` (made whole in a temporary folder, then renamed; reused when it matches).

    Args:
        target: the folder.
        files: ``{relative path: content}``.

    Returns:
        ``target``.
    """
    wanted = {rel: hashlib.sha256(data).hexdigest() for rel, data in files.items()}

    def matches() -> bool:
        present = {p.relative_to(target).as_posix() for p in target.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
        return present == set(wanted) and all(
            hashlib.sha256((target / r).read_bytes()).hexdigest() == h for r, h in wanted.items()
        )

    if target.is_dir() and matches():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.partial-{uuid.uuid4().hex[:12]}"
    try:
        for rel, data in files.items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_bytes(data)
        if target.exists():
            shutil.rmtree(target, ignore_errors=True)
        try:
            os.rename(tmp, target)
        except OSError:
            if not matches():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return target


def entry_slug(entry: str) -> str:
    """A name part for an entry file (``envs/Task.py`` -> ``envs_Task``), empty for the default ``env.py``."""
    return "" if entry == DEFAULT_ENTRY else re.sub(r"[^A-Za-z0-9_.-]", "_", entry.removesuffix(".py"))


# --- the load ----------------------------------------------------------------------------------------------------------


def load_plain(
    ref: PlainRef,
    *,
    trust_remote_code: bool,
    check: bool,
    token: str | None,
    cache_dir: str | Path | None,
    iso: IsolationOptions,
    content_digest: str | None = None,
    stacklevel: int = 3,
) -> LoadedEnv:
    """Load a plain LeRobot EnvHub repo: resolve, fetch and hash (:func:`fetch_plain`), warn when unpinned, the trust
    gate (consent bound to repo@sha and the digest of its files, as ``hub-envs trust`` records it), the requirements
    preflight (its ``requirements.txt``), the code folder (the repo's files and the adapter), register, and (``check``)
    make one env to hold it to LeRobot's contract.

    Args:
        ref: the reference (:func:`parse_hub_path`).
        trust_remote_code, check, token, cache_dir: as :func:`hub_envs.load_env` takes them.
        iso: the isolation options.
        content_digest: the digest of the files consent was given for (a Ray worker gets its driver's); other content
            is refused before anything of it is imported.
        stacklevel: of the warnings.

    Returns:
        A :class:`LoadedEnv` whose ``missing_guarantees`` lists what it cannot give.

    Raises:
        UntrustedCodeError: no consent for this commit and content, or content other than ``content_digest``.
        MissingRequirementsError: a requirement of ``requirements.txt`` is not installed.
        EnvContractError: the entry file breaks LeRobot's EnvHub contract (no ``make_env``, another return type).
        EnvCodeError: the repo's code raised.
    """
    report = LoadReport()
    trusted = trust_list.read_trust_list()  # before any download: nothing a download writes can change it
    src = fetch_plain(ref, token=token, cache_dir=cache_dir)
    check_not_published_by_push_env(src)
    report.integrity = f"{len(src.files)} files hashed (no manifest to verify them against)"
    if src.ref.revision != src.sha:
        warnings.warn(
            f"{ref.repo}: revision {ref.revision or 'main'!r} resolved to {src.sha}. Pin it for reproducible results: "
            f'load_env("{ref.text(src.sha)}")',
            UnpinnedRevisionWarning,
            stacklevel=stacklevel,
        )
    source_manifest = Manifest(
        name=ref.repo.split("/")[1],
        env_entry_point=ENV_ENTRY_POINT,
        config_entry_point=CONFIG_ENTRY_POINT,
        gym_id=ref.repo,
        env_type=ref.repo,
        files=src.files,
        content_digest=src.digest,
        repo_id=ref.repo,
        requirements=src.requirements,
    )
    _check_content_digest(content_digest, source_manifest, src.where)  # before consent: a binding it was given for
    try:
        report.trust = _trust_gate(ref.repo, src.sha, source_manifest, src.path, trust_remote_code, trusted)
    except UntrustedCodeError as e:  # its load line names the entry file too, and what changed since a trusted commit
        if MANIFEST_FILE in src.files:  # a hub-envs repo by an entry file: its trust entry binds its manifest's digest
            raise UntrustedCodeError(
                f"{src.where} is a hub-envs repo (it has {MANIFEST_FILE}), loaded here as a plain EnvHub repo by an entry "
                f"file ({safe_text(ref.entry)}); nothing was imported. Consent recorded for it (hub-envs trust) covers the "
                f"files its manifest lists, checked against it, so it does not cover this load: load it as a hub-envs repo, "
                f'load_env("{src.where}"), or pass trust_remote_code=True: load_env("{ref.text(src.sha)}", '
                f"trust_remote_code=True)."
            ) from None
        message = str(e).replace(f'load_env("{src.where}"', f'load_env("{ref.text(src.sha)}"')
        raise UntrustedCodeError(message + _changed_since_trusted(src, trusted)) from None
    report.requirements = list(src.requirements)
    if iso.isolation != "venv":  # a venv worker installs them
        from hub_envs.repo.requirements import check_requirements  # heavy-ish: importlib.metadata, packaging

        check_requirements(src.requirements, repo=src.where)
    slug = entry_slug(ref.entry)
    adapter = render_adapter(ref.text(src.sha), ref.entry)
    files = code_folder_files(src, adapter)
    code = write_folder(hub_envs_home() / "plain" / ("models--" + ref.repo.replace("/", "--")) / src.sha / (slug or "env"), files)
    key = module_key(ref.repo, src.sha, slug or "env")
    imported_before = is_imported(key)
    try:
        package = import_env_folder(code, key)  # the adapter's config imports nothing of the repo
        config_class = resolve_entry_point(package, CONFIG_ENTRY_POINT, where=f"{src.where}: adapter")
        validate_config_class(config_class, where=src.where)
        config = instantiate_config(config_class, where=src.where)
        manifest = Manifest(
            **{
                **{f: getattr(source_manifest, f) for f in ("name", "env_entry_point", "config_entry_point", "repo_id")},
                "gym_id": f"{ref.repo}-{slug}" if slug else ref.repo,
                "env_type": f"{ref.repo}-{slug}" if slug else ref.repo,
                "files": {rel: hashlib.sha256(data).hexdigest() for rel, data in files.items()},
                "content_digest": src.digest,
                "requirements": src.requirements,
                "config": encode_config(config),
                "description": f"plain LeRobot EnvHub repo {ref.text(src.sha)}",
            }
        )
        if not iso.isolated:  # in-process: the tasks are found here (isolated: in a worker, by _register)
            manifest, config = as_suite(manifest, config_class, config, discover_tasks(package, where=f"{src.where}:{ref.entry}"))
        loaded = _register(src, manifest, package, code, key, config_class, config, iso, report, token, cache_dir, check)
    except BaseException:
        if not imported_before:
            forget_env_folder(key)
        raise
    loaded.plain_source = ref.text(src.sha)
    loaded.missing_guarantees = MISSING_GUARANTEES
    report.fingerprint = "none recorded (a plain EnvHub repo)"
    for note in src.requirement_notes:
        report.requirements.append(f"({note})")
    warnings.warn(
        f"{src.where} is a plain LeRobot EnvHub repo (no hub_env.json), loaded with consent; hub-envs cannot give: "
        + "; ".join(MISSING_GUARANTEES)
        + f". `hub-envs audit --repo_id={ref.text(src.sha)}` checks it against LeRobot's conventions; "
        f"`hub-envs adopt` publishes it with all of them.",
        PlainRepoWarning,
        stacklevel=stacklevel,
    )
    remember(loaded)
    return loaded


def _register(src, manifest, package, code, key, config_class, config, iso, report, token, cache_dir, check) -> LoadedEnv:
    """Register the adapter (in-process: its class; isolated: the proxies' factory) in one registry transaction, and
    (check) make one env to hold the entry file to the contract: a failure leaves the registries as they were."""
    where = src.where
    with registration.registry_transaction() as txn:
        if iso.isolated:
            entry_point, _, _ = isolated_parts(src.ref.repo, src.sha, code, key, manifest, None, iso)
            iso = entry_point.options
        else:
            entry_point = resolve_entry_point(package, ENV_ENTRY_POINT, where=f"{where}: adapter")
        suffix = isolation_suffix(iso) if iso.isolated else ""
        reg = registration.register(
            gym_id=f"{manifest.gym_id}-{src.sha[:12]}{suffix}",
            env_type=f"{manifest.env_type}@{src.sha[:12]}{suffix}",
            owner=f"{where}:{src.ref.entry}" + (f" ({suffix.lstrip('-')})" if iso.isolated else ""),
            entry_point=entry_point,
            config_class=config_class,
            max_episode_steps=int(config.episode_length),
            kwargs={},
            disable_env_checker=True,
        )
        loaded = LoadedEnv(
            repo_id=src.ref.repo,
            revision=src.sha,
            requested_revision=src.ref.revision,
            path=src.path,
            manifest=manifest,
            env_class=entry_point,
            config_class=config_class,
            config=config,
            registration=reg,
            report=report,
            isolation=iso,
            token=token,
            cache_dir=cache_dir,
        )
        if check:
            check_contract(loaded, where=f"{where}:{src.ref.entry}")
        if iso.isolated:  # the suite's tasks, found where the repo's code runs
            tasks = discover_tasks(
                lambda: describe_in_worker(loaded.gym_id, iso, f"{ENV_MODULE}:describe_suite"), where=f"{where}:{src.ref.entry}"
            )
            loaded.manifest, loaded._config = as_suite(manifest, config_class, config, tasks)  # (config: a cached property)
        replaced, _ = txn.replaced_by(code)
        if replaced:
            raise RegistrationConflictError(
                f"{where}: its code replaced {', '.join(replaced)}, already registered by another package, with an entry "
                f"of its own. Remove the env code's own gym.register / @EnvConfig.register_subclass calls."
            )
    return loaded


def as_suite(manifest: Manifest, config_class: type, config: Any, tasks: tuple[dict[str, Any], ...]) -> tuple[Manifest, Any]:
    """A plain load's manifest and config for the tasks :func:`discover_tasks` found: none, as they are; a suite, the
    manifest holds the tasks (format 4), is named after the suite (``make_suite``'s key, as the source's ``make_env``
    gives it) and the config names the first task (the one ``make`` makes).

    Args:
        manifest: the load's manifest.
        config_class: the adapter's config class.
        config: its instance.
        tasks: the tasks.

    Returns:
        ``(manifest, config)``.
    """
    if not tasks:
        return manifest, config
    suites = list(dict.fromkeys(str(t["suite"]) for t in tasks))
    where = manifest.description
    config = instantiate_config(config_class, where=where, overrides={"task": tasks[0]["task"]})
    name = suites[0] if len(suites) == 1 else manifest.name
    suite = dataclasses.replace(
        manifest, name=name, format_version=SUITE_FORMAT_VERSION, tasks=tasks, config=encode_config(config)
    )
    return suite, config


def discover_tasks(package: Any, *, where: str) -> tuple[dict[str, Any], ...]:
    """The tasks of an entry file whose ``make_env`` returns the suite form ``{suite: {task_id: VectorEnv}}`` with more
    than one task (the adapter's ``describe_suite``: every env made once, ``n_envs=1``, and closed), as a suite
    manifest's ``tasks`` records: ``task`` (the env's ``task``, else ``<suite>/<task_id>``), ``task_index``,
    ``instruction`` (the env's ``task_description``, else its ``task``, else the name), and the source's ``suite`` and
    ``task_id``.

    Args:
        package: the imported code folder; or, for an isolated load, a function calling the adapter's ``describe_suite``
            in a worker.
        where: names the repo, commit and entry file in messages.

    Returns:
        The records, in the order ``make_env`` gives them; ``()`` for one env (or a suite of one task).

    Raises:
        EnvContractError: ``make_env`` returns a dict that is not the suite form, or another type.
        EnvCodeError: the repo's code raised.
    """
    if callable(package):  # an isolated load: the adapter's describe_suite, called in a worker
        describe = package
    else:
        describe = vars(sys.modules[resolve_entry_point(package, ENV_ENTRY_POINT, where=where).__module__])["describe_suite"]
    try:
        found = describe()
    except TypeError as e:
        if "breaks LeRobot's EnvHub contract" in str(e):
            raise EnvContractError(f"{safe_text(e)} Nothing was registered.") from e
        raise EnvCodeError(f"{where}: its make_env(n_envs=1, use_async_envs=False) raised TypeError: {safe_text(e)}") from e
    except HubEnvsError as e:
        if "breaks LeRobot's EnvHub contract" in str(e):  # from a worker: the adapter's TypeError, as it said it
            raise EnvContractError(f"{safe_text(e)} Nothing was registered.") from e
        raise
    except Exception as e:
        raise EnvCodeError(
            f"{where}: its make_env(n_envs=1, use_async_envs=False) raised {type(e).__name__}: {safe_text(e)}"
        ) from e
    return tuple({**d, "task_index": i} for i, d in enumerate(found))


def _changed_since_trusted(src: PlainSource, trusted: trust_list.TrustList) -> str:
    """What changed since the last commit of the repo trusted before, when its snapshot is in the cache (a plain repo
    has no manifest listing its files: they are hashed here)."""
    previous = [e for e in trusted.previous(src.ref.repo) if e.sha != src.sha]
    folder = src.path.parent / previous[-1].sha if previous else None
    if folder is None or not folder.is_dir():
        return ""
    names = [p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file() and p.name != ".gitattributes"]
    old = hash_files(folder, names)
    changed = sorted(p for p in set(old) | set(src.files) if old.get(p) != src.files.get(p))
    return f"\nFiles changed since {previous[-1].sha[:12]}, the commit you trusted: {', '.join(safe_text(p) for p in changed)}."


def check_contract(loaded: LoadedEnv, *, where: str) -> None:
    """Make one env of a plain load and close it: an entry file that breaks LeRobot's EnvHub contract is refused here,
    with :class:`EnvContractError` naming what is wrong, not at the first ``gym.make`` of a user.

    Args:
        loaded: the registered load.
        where: names the repo, commit and entry file.

    Raises:
        EnvContractError: no ``make_env``, or it returns something other than one env.
        EnvCodeError: the repo's code raised.
    """
    try:
        env = gym.make(loaded.gym_id)
    except HubEnvsError as e:
        if "breaks LeRobot's EnvHub contract" in str(e):
            raise EnvContractError(str(e)) from e
        raise
    except TypeError as e:
        if "breaks LeRobot's EnvHub contract" in str(e):
            raise EnvContractError(f"{safe_text(e)} Nothing was registered.") from e
        raise EnvCodeError(f"{where}: making the env raised TypeError: {safe_text(e)}") from e
    except Exception as e:
        raise EnvCodeError(
            f"{where}: its make_env(n_envs=1, use_async_envs=False) raised {type(e).__name__}: {safe_text(e)}"
        ) from e
    env.close()


def check_not_published_by_push_env(src: PlainSource) -> None:
    """Refuse a repo push_env published whose ``hub_env.json`` is gone: its ``env.py`` is push_env's, which needs the
    manifest, so loading it as a plain repo could only fail later with a less useful error.

    Args:
        src: the fetched repo.

    Raises:
        ManifestError: the entry file is push_env's ``env.py`` and the commit holds no manifest.
    """
    entry = src.path / src.ref.entry
    template = (PACKAGE_DIR / "templates" / "env_entry.py").read_text(encoding="utf-8").partition("\n")[0]
    try:
        with open(entry, encoding="utf-8", errors="replace") as f:
            first = f.readline().rstrip("\n")
    except OSError:
        return
    if first == template:
        raise ManifestError(
            f"{src.where}: {MANIFEST_FILE} is missing, though its {src.ref.entry} was written by push_env: the commit lost "
            f"its manifest, without which nothing of it can be verified. Re-publish the env with `push_env --env_dir=...`."
        )


def is_plain_snapshot_error(error: BaseException) -> bool:
    """Whether a load failed only because the repo has no ``hub_env.json`` (a plain EnvHub repo, loaded instead).

    Args:
        error: what resolving the repo raised.

    Returns:
        True for the missing-manifest error.
    """
    return (
        isinstance(error, InvalidRepoFormatError)
        and f"{MANIFEST_FILE} is missing" in str(error)
        or ("has no hub_env.json" in str(error))
    )


__all__ = [
    "MISSING_GUARANTEES",
    "PlainRef",
    "PlainSource",
    "fetch_plain",
    "load_plain",
    "parse_hub_path",
    "render_adapter",
]
