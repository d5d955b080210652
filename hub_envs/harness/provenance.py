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
from importlib import metadata
from typing import Any

from packaging.requirements import InvalidRequirement, Requirement
from packaging.utils import canonicalize_name

from hub_envs.requirements import installed_version

CORE_PACKAGES = ("numpy", "gymnasium", "lerobot", "torch", "huggingface_hub", "draccus", "hub-envs")


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


def worker_provenance(loaded: Any) -> dict[str, Any] | None:
    """For a venv-isolated load (``loaded.worker_venv``): where the env ran (venv, python, every installed package,
    notes) and the versions of the packages the manifest records, as the worker has them; else None."""
    record = loaded.worker_venv
    if record is None:
        return None
    installed = {
        canonicalize_name(k): v for k, v in (line.split("==", 1) for line in record.get("installed", []) if "==" in line)
    }
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


def run_provenance(loaded: Any) -> dict[str, Any]:
    """What every report of a run on ``loaded`` (a :class:`hub_envs.load.LoadedEnv`) records first: the repo, the
    revision asked for and the sha it resolved to, the content digest, the published dataset fingerprint, the
    package versions the env's code ran with (:func:`versions_run_with`), hub-envs' version and when."""
    from hub_envs import __version__

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


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, ``sysctl`` on macOS), else ``platform.processor()``."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith(("model name", "hardware", "cpu model")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    if platform.system() == "Darwin":
        import subprocess

        try:
            out = subprocess.run(["sysctl", "-n", "machdep.cpu.brand_string"], capture_output=True, text=True, timeout=5)
            if out.returncode == 0 and out.stdout.strip():
                return out.stdout.strip()
        except (OSError, subprocess.SubprocessError):
            pass
    return platform.processor() or platform.machine() or "unknown"


def requirement_closure(
    requirements: tuple[str, ...] | list[str] = (), *, also: tuple[str, ...] = ("numpy", "gymnasium")
) -> dict[str, str]:
    """The installed version of every distribution ``requirements`` (and ``also``: what an env worker needs
    itself) pull in, transitively, with environment markers and extras evaluated as pip would here:
    ``{canonical name: version}``. What ``versions="publisher"`` pins beyond the requirements themselves.
    A requirement that is not installed is left out (the preflight reports it)."""
    pending: list[tuple[Requirement, frozenset[str]]] = []
    for text in [*requirements, *also]:
        try:
            pending.append((Requirement(text), frozenset({""})))
        except InvalidRequirement:
            continue
    closure: dict[str, str] = {}
    extras_seen: dict[str, set[str]] = {}
    while pending:
        req, parent_extras = pending.pop()
        if req.marker is not None and not any(req.marker.evaluate({"extra": e}) for e in parent_extras):
            continue
        name = canonicalize_name(req.name)
        wanted = set(req.extras) | {""}
        if name in closure and wanted <= extras_seen[name]:
            continue
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
        closure[name] = dist.version
        extras_seen.setdefault(name, set()).update(wanted)
        for text in dist.requires or ():
            try:
                pending.append((Requirement(text), frozenset(extras_seen[name])))
            except InvalidRequirement:
                continue
    return dict(sorted(closure.items()))


def version_differences(recorded: dict[str, str], current: dict[str, str]) -> dict[str, tuple[str, str]]:
    """``{package: (published, here)}`` for every package whose version differs."""
    return {
        k: (recorded.get(k, "?"), current.get(k, "?"))
        for k in sorted(set(recorded) | set(current))
        if recorded.get(k) != current.get(k) and k in recorded
    }


def describe_differences(diffs: dict[str, tuple[str, str]]) -> str:
    """The sentence a drift message ends with: which versions differ, or that none does (then the code or machine did)."""
    if not diffs:
        return (
            "\nNo package version differs from the publisher's, so the env's code or assets, or the machine "
            "(CPU, OS, libraries outside Python), changed."
        )
    return "\nVersions differ from the publisher's: " + ", ".join(
        f"{k} {a} (published) vs {b} (here)" for k, (a, b) in diffs.items()
    )
