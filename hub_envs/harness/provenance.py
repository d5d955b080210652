"""Provenance: the versions of everything a result depends on, recorded and compared.

Example:
    >>> from hub_envs.harness.provenance import package_versions
    >>> sorted(package_versions())[:3]
    ['draccus', 'gymnasium', 'hub-envs']
"""

from __future__ import annotations

import platform

from packaging.requirements import InvalidRequirement, Requirement

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
