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
    """python, the core packages, and every package named in ``requirements`` (the simulator)."""
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
    """Every package version ``manifest`` records: ``versions`` (python, the core packages, each requirement's
    package), then the rest of ``resolved`` (:func:`closure_only`)."""
    return {**dict(manifest.versions), **closure_only(manifest)}


def closure_only(manifest: Any) -> dict[str, str]:
    """The versions of ``manifest``'s ``resolved`` (format 3: the requirements' dependency closure, the simulator a
    requirement pulls in included) that ``versions`` does not record already (under any spelling)."""
    named = {canonicalize_name(k) for k in manifest.versions}
    return {k: v for k, v in dict(getattr(manifest, "resolved", {}) or {}).items() if canonicalize_name(k) not in named}


def _worker_installed(record: dict[str, Any]) -> dict[str, str]:
    return {canonicalize_name(k): v for k, v in (line.split("==", 1) for line in record.get("installed", []) if "==" in line)}


def worker_provenance(loaded: Any) -> dict[str, Any] | None:
    """For a venv-isolated load (``loaded.worker_venv``): where the env ran (venv, python, every installed package,
    notes) and the versions of the packages the manifest records, as the worker has them; else None."""
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
    """The package versions ``loaded``'s code runs with: this process's (:func:`package_versions` of its
    requirements), or, isolated in a venv, the worker's where it has them (python included)."""
    here = package_versions(loaded.manifest.requirements)
    worker = worker_provenance(loaded)
    return {**here, **worker["versions"]} if worker is not None else here


def closure_run_with(loaded: Any) -> dict[str, str]:
    """For each package of the manifest's dependency closure that ``versions`` does not name (:func:`closure_only`):
    the version ``loaded``'s code runs with (this process's, or a venv worker's), or ``"not installed"``."""
    names = closure_only(loaded.manifest)
    record = loaded.worker_venv
    if record is None:
        return {k: _version(k) for k in names}
    installed = _worker_installed(record)  # a venv worker has only what its venv holds
    return {k: installed.get(canonicalize_name(k), "not installed") for k in names}


def run_provenance(loaded: Any) -> dict[str, Any]:
    """What every report of a run on ``loaded`` (a :class:`hub_envs.loading.loaded.LoadedEnv`) records first: the repo, the
    revision asked for and the sha it resolved to, the content digest, the published dataset fingerprint, the
    package versions the env's code ran with (:func:`versions_run_with`), hub-envs' version and when."""
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
    """``{package: (published, here)}`` for every package whose version differs."""
    return {
        k: (recorded.get(k, "?"), current.get(k, "?"))
        for k in sorted(set(recorded) | set(current))
        if recorded.get(k) != current.get(k) and k in recorded
    }


def drift_kinds(names, manifest: Any) -> dict[str, str]:
    """What each of ``names`` (packages whose recorded version differs) is to the env of ``manifest``, a key of
    :data:`DRIFT_KINDS`: one of its ``requirements``; a ``dependency`` of them (in ``resolved``, the requirements'
    closure the publisher had, less what only numpy and gymnasium pull in here); the ``simulator`` (a physics
    engine, :data:`SIMULATORS`); numpy, gymnasium and their own dependencies (``worker``: what every env runs
    on); else the ``stack`` (python, lerobot, torch, ...)."""
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
    """``{package: (published, here)}`` for every version ``manifest`` records (:func:`recorded_versions`) that
    differs from ``here``, the most suspect first: the env's requirements, their dependencies (a simulator first),
    the simulator, numpy and gymnasium, then the rest of the stack (:func:`drift_kinds`); by name within each."""
    diffs = version_differences(recorded_versions(manifest), here)
    kinds = drift_kinds(diffs, manifest)
    order = list(DRIFT_KINDS)
    return dict(
        sorted(diffs.items(), key=lambda kv: (order.index(kinds[kv[0]]), canonicalize_name(kv[0]) not in SIMULATORS, kv[0]))
    )


def describe_differences(diffs: dict[str, tuple[str, str]], kinds: dict[str, str] | None = None) -> str:
    """The sentence a drift message ends with: which versions differ (in ``diffs``' order, each with its kind when
    ``kinds`` says it), or that none does (then the code or machine did)."""
    if not diffs:
        return (
            "\nNo package version differs from the publisher's, so the env's code or assets, or the machine "
            "(CPU, OS, libraries outside Python), changed."
        )
    return "\nVersions differ from the publisher's: " + difference_text(diffs, kinds)


def difference_text(diffs: dict[str, tuple[str, str]], kinds: dict[str, str] | None = None) -> str:
    """``"mujoco 3.3.0 (published) vs 3.3.7 (here, a dependency of its requirements), ..."``."""
    kinds = kinds or {}
    return ", ".join(
        f"{k} {a} (published) vs {b} (here{', ' + DRIFT_KINDS[kinds[k]] if k in kinds else ''})" for k, (a, b) in diffs.items()
    )


def drift_note(loaded: Any) -> str:
    """:func:`describe_differences` for ``loaded`` (a :class:`hub_envs.loading.loaded.LoadedEnv`): the recorded versions that
    differ from those its code runs with (:func:`versions_run_with`, :func:`closure_run_with`), ranked
    (:func:`ranked_differences`)."""
    diffs = ranked_differences(loaded.manifest, {**closure_run_with(loaded), **versions_run_with(loaded)})
    return describe_differences(diffs, drift_kinds(diffs, loaded.manifest))
