"""Provenance: the versions of everything a result depends on, recorded and compared.

Example:
    >>> from hub_envs.harness.provenance import package_versions, requirement_closure
    >>> sorted(package_versions())[:3]
    ['draccus', 'gymnasium', 'hub-envs']
    >>> closure = requirement_closure(["gymnasium>=1.0"])   # gymnasium and what it pulls in, as installed
    >>> {"gymnasium", "numpy", "cloudpickle"} <= set(closure), closure["numpy"] == package_versions()["numpy"]
    (True, True)
"""

from __future__ import annotations

import datetime as _dt
import platform
from typing import Any

from packaging.requirements import InvalidRequirement, Requirement
from packaging.utils import canonicalize_name

from hub_envs._stack import CORE_PACKAGES, installed_version, requirement_closure
from hub_envs._version import __version__

#: physics engines (PyPI names): among the packages a rollout depends on, the first suspects when it drifts
SIMULATORS = frozenset(
    {"mujoco", "mujoco-mjx", "pybullet", "dm-control", "box2d", "box2d-py", "pymunk", "brax", "sapien", "genesis-world"}
)
#: the kinds of a recorded version that differs, most suspect first (:func:`ranked_differences`)
DRIFT_KINDS = {
    "requirement": "a requirement of the env",
    "dependency": "a dependency of its requirements",
    "simulator": "the simulator",
    "worker": "what every env runs on",
    "stack": "this stack",
}


def _version(name: str) -> str:
    return installed_version(name) or "not installed"


def package_versions(requirements: tuple[str, ...] | list[str] = ()) -> dict[str, str]:
    """The versions a result depends on, as installed here.

    Args:
        requirements: the env's requirements (their packages are added: the simulator).

    Returns:
        ``{package: version}`` of python, the core packages and each requirement's package (``"not installed"``).
    """
    names = list(CORE_PACKAGES)
    for text in requirements:
        try:
            names.append(Requirement(text).name)
        except InvalidRequirement:
            continue
    versions = {name: _version(name) for name in dict.fromkeys(names)}
    versions["python"] = platform.python_version()
    return dict(sorted(versions.items()))


def recorded_versions(manifest: Any) -> dict[str, str]:
    """Every package version a manifest records: ``versions`` (python, the core packages, each requirement's package), then
    the rest of ``resolved`` (:func:`closure_only`).

    Args:
        manifest: a :class:`~hub_envs.repo.format.Manifest`.

    Returns:
        ``{package: version}``.
    """
    return {**dict(manifest.versions), **closure_only(manifest)}


def closure_only(manifest: Any) -> dict[str, str]:
    """The versions of a manifest's ``resolved`` (the requirements' dependency closure, the simulator a requirement pulls in
    included) that ``versions`` does not record already (under any spelling).

    Args:
        manifest: a :class:`~hub_envs.repo.format.Manifest`.

    Returns:
        ``{package: version}``.
    """
    named = {canonicalize_name(k) for k in manifest.versions}
    return {k: v for k, v in dict(getattr(manifest, "resolved", {}) or {}).items() if canonicalize_name(k) not in named}


def _worker_installed(record: dict[str, Any]) -> dict[str, str]:
    return {canonicalize_name(k): v for k, v in (line.split("==", 1) for line in record.get("installed", []) if "==" in line)}


def worker_provenance(loaded: Any) -> dict[str, Any] | None:
    """Where a venv-isolated load's env ran.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Returns:
        For ``isolation="venv"``: the venv, its python, every installed package, the notes, and the versions of the
        packages the manifest records as the worker has them; else None.
    """
    record = loaded.worker_venv
    if record is None:
        return None
    installed = _worker_installed(record)
    versions = {k: installed[canonicalize_name(k)] for k in loaded.manifest.versions if canonicalize_name(k) in installed}
    versions["python"] = record.get("python")
    return {
        "venv": record.get("path"),
        "python": record.get("python"),
        "installed": list(record.get("installed", [])),
        "notes": list(record.get("notes", [])),
        "versions": versions,
    }


def versions_run_with(loaded: Any) -> dict[str, str]:
    """The package versions a loaded env's code runs with.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Returns:
        This process's (:func:`package_versions` of its requirements), or, isolated in a venv, the worker's where it has
        them (python included).
    """
    here = package_versions(loaded.manifest.requirements)
    worker = worker_provenance(loaded)
    return {**here, **worker["versions"]} if worker is not None else here


def closure_run_with(loaded: Any) -> dict[str, str]:
    """The versions the env's code runs with of the manifest's dependency closure beyond ``versions`` (:func:`closure_only`).

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Returns:
        ``{package: version or "not installed"}`` (a venv worker's, when it runs in one).
    """
    names = closure_only(loaded.manifest)
    record = loaded.worker_venv
    if record is None:
        return {k: _version(k) for k in names}
    installed = _worker_installed(record)  # a venv worker has only what its venv holds
    return {k: installed.get(canonicalize_name(k), "not installed") for k in names}


def run_provenance(loaded: Any) -> dict[str, Any]:
    """What every report of a run records first.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Returns:
        The repo, the revision asked for and the sha it resolved to, the content digest, the published dataset
        fingerprint, the package versions the env's code ran with (:func:`versions_run_with`), hub-envs' version and when.
    """
    m = loaded.manifest
    return {
        "repo_id": loaded.repo_id,
        "requested_revision": loaded.requested_revision,
        "sha": loaded.revision,
        "content_digest": m.content_digest,
        "published_dataset_fingerprint": m.dataset.get("fingerprint"),
        "versions_here": versions_run_with(loaded),
        "hub_envs_version": __version__,
        "generated_at": _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat(),
    }


def version_differences(recorded: dict[str, str], current: dict[str, str]) -> dict[str, tuple[str, str]]:
    """The packages whose version differs.

    Args:
        recorded: the published versions.
        current: the versions here.

    Returns:
        ``{package: (published, here)}`` for each package ``recorded`` names whose version differs.
    """
    return {
        k: (recorded.get(k, "?"), current.get(k, "?"))
        for k in sorted(set(recorded) | set(current))
        if recorded.get(k) != current.get(k) and k in recorded
    }


def drift_kinds(names, manifest: Any) -> dict[str, str]:
    """What each package whose recorded version differs is to the env.

    Args:
        names: the packages.
        manifest: the env's manifest.

    Returns:
        ``{package: kind}``, a key of :data:`DRIFT_KINDS`: one of its ``requirements``; a ``dependency`` of them (in
        ``resolved``, less what only numpy and gymnasium pull in here); the ``simulator`` (:data:`SIMULATORS`);
        ``worker`` (numpy, gymnasium and their own dependencies); else the ``stack`` (python, lerobot, torch, ...).
    """
    requirements = set()
    for text in manifest.requirements:
        try:
            requirements.add(canonicalize_name(Requirement(text).name))
        except InvalidRequirement:
            continue
    resolved = {canonicalize_name(k) for k in getattr(manifest, "resolved", {}) or {}}
    worker_only = set(requirement_closure((), also=("numpy", "gymnasium"))) - set(
        requirement_closure(manifest.requirements, also=())
    )
    out = {}
    for name in names:
        c = canonicalize_name(name)
        if c in requirements:
            out[name] = "requirement"
        elif c in ("numpy", "gymnasium") or c in worker_only:
            out[name] = "worker"
        elif c in resolved:
            out[name] = "dependency"
        elif c in SIMULATORS:
            out[name] = "simulator"
        else:
            out[name] = "stack"
    return out


def ranked_differences(manifest: Any, here: dict[str, str]) -> dict[str, tuple[str, str]]:
    """The recorded versions (:func:`recorded_versions`) that differ from ``here``, the most suspect first: the env's
    requirements, their dependencies (a simulator first), the simulator, numpy and gymnasium, then the rest of the stack
    (:func:`drift_kinds`); by name within each.

    Args:
        manifest: the env's manifest.
        here: the versions the env's code runs with.

    Returns:
        ``{package: (published, here)}``, ranked.
    """
    diffs = version_differences(recorded_versions(manifest), here)
    kinds = drift_kinds(diffs, manifest)
    order = list(DRIFT_KINDS)
    return dict(
        sorted(diffs.items(), key=lambda kv: (order.index(kinds[kv[0]]), canonicalize_name(kv[0]) not in SIMULATORS, kv[0]))
    )


def describe_differences(diffs: dict[str, tuple[str, str]], kinds: dict[str, str] | None = None) -> str:
    """The sentence a drift message ends with.

    Args:
        diffs: ``{package: (published, here)}``, in the order to say them.
        kinds: each package's kind (:func:`drift_kinds`), when known.

    Returns:
        Which versions differ, or that none does (then the code, the assets or the machine changed).
    """
    if not diffs:
        return (
            "\nNo package version differs from the publisher's, so the env's code or assets, or the machine "
            "(CPU, OS, libraries outside Python), changed."
        )
    return "\nVersions differ from the publisher's: " + difference_text(diffs, kinds)


def difference_text(diffs: dict[str, tuple[str, str]], kinds: dict[str, str] | None = None) -> str:
    """``"mujoco 3.3.0 (published) vs 3.3.7 (here, a dependency of its requirements), ..."``.

    Args:
        diffs: ``{package: (published, here)}``.
        kinds: each package's kind, when known.

    Returns:
        The text.
    """
    kinds = kinds or {}
    return ", ".join(
        f"{k} {a} (published) vs {b} (here{', ' + DRIFT_KINDS[kinds[k]] if k in kinds else ''})" for k, (a, b) in diffs.items()
    )


def drift_note(loaded: Any) -> str:
    """:func:`describe_differences` for a loaded env: the recorded versions that differ from those its code runs with
    (:func:`versions_run_with`, :func:`closure_run_with`), ranked (:func:`ranked_differences`).

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Returns:
        The sentence.
    """
    diffs = ranked_differences(loaded.manifest, {**closure_run_with(loaded), **versions_run_with(loaded)})
    return describe_differences(diffs, drift_kinds(diffs, loaded.manifest))
