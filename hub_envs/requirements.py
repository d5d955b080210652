"""Requirements preflight: are the packages an env repo declares installed, at compatible versions?

Nothing is ever installed automatically; the error lists what is missing and the pip command.

Example:
    >>> from hub_envs.requirements import unmet_requirements
    >>> unmet_requirements(["numpy>=1.0"])
    []
"""

from __future__ import annotations

import importlib.metadata as md
import shlex

from packaging.requirements import InvalidRequirement, Requirement

from hub_envs.errors import ManifestError, MissingRequirementsError


def installed_version(name: str) -> str | None:
    """The installed version of distribution ``name``, or None.

    Same answer as ``importlib.metadata.version`` but reads only the header of METADATA instead of
    parsing the whole file (long descriptions make that ~1 ms per package, on every load_env).
    """
    try:
        dist = md.distribution(name)
    except md.PackageNotFoundError:
        return None
    text = dist.read_text("METADATA") or dist.read_text("PKG-INFO") or ""
    for line in text.splitlines():
        if not line:
            break  # end of the headers
        if line.startswith("Version:"):
            return line[len("Version:") :].strip()
    return dist.version


def unmet_requirements(requirements: list[str] | tuple[str, ...]) -> list[tuple[str, str]]:
    """``(requirement, why)`` for each requirement that is not satisfied in this environment."""
    unmet = []
    for text in requirements:
        try:
            req = Requirement(text)
        except InvalidRequirement as e:
            raise ManifestError(f"Requirement {text!r} is not valid ({e}). Fix the repo's dependencies.") from None
        if req.marker is not None and not req.marker.evaluate():
            continue
        installed = installed_version(req.name)
        if installed is None:
            unmet.append((text, "not installed"))
            continue
        if req.specifier and not req.specifier.contains(installed, prereleases=True):
            unmet.append((text, f"installed {installed}"))
    return unmet


def check_requirements(requirements, *, repo: str) -> None:
    """Raise :class:`MissingRequirementsError` listing every unmet requirement with the pip line."""
    unmet = unmet_requirements(requirements)
    if unmet:
        lines = "\n".join(f"  {req:<30} {why}" for req, why in unmet)
        pip = "pip install " + " ".join(shlex.quote(req) for req, _ in unmet)
        raise MissingRequirementsError(
            f"{repo} requires packages this environment does not have:\n{lines}\n"
            f"Install them (hub-envs never installs anything itself):\n  {pip}"
        )
