"""The requirements preflight: are the packages an env repo declares installed, at compatible versions? Nothing is installed
for you.

Example:
    >>> from hub_envs.repo.requirements import unmet_requirements
    >>> unmet_requirements(["numpy>=1.0"])
    []
"""

from __future__ import annotations

import importlib.metadata as md
import shlex
import warnings
from dataclasses import dataclass

from packaging.requirements import InvalidRequirement, Requirement
from packaging.utils import canonicalize_name

from hub_envs._stack import installed_version
from hub_envs.errors import ManifestError, MissingRequirementsError, RequirementStandInWarning


@dataclass(frozen=True)
class StandIn:
    """An installed distribution that provides the import name of a requirement that is not installed itself."""

    requirement: str  # as the repo declares it, e.g. "pygame>=2.1"
    module: str  # the import name, e.g. "pygame"
    distribution: str  # who provides it, e.g. "pygame-ce"
    version: str  # that distribution's version
    satisfies: bool  # its version is within the requirement's specifier (versions of a fork usually follow the original's)

    def describe(self) -> str:
        """``import <module>`` comes from ``<distribution> <version>`` (and, when so, that it is outside the requirement)."""
        within = "" if self.satisfies else f", outside {Requirement(self.requirement).specifier}"
        return f"`import {self.module}` comes from {self.distribution} {self.version}{within}"


def stand_in(req: Requirement, *, _provided: dict[str, list[str]] | None = None) -> StandIn | None:
    """The installed distribution that provides the import name of a requirement whose own distribution is not installed.

    Uses :func:`importlib.metadata.packages_distributions` (which reads every installed distribution's file list: only
    ever called for a requirement that is not installed).

    Args:
        req: the requirement (its name in import form: ``pygame``, ``gymnasium_robotics``).
        _provided: ``packages_distributions()``, when the caller read it already.

    Returns:
        The :class:`StandIn`, or None.
    """
    module = canonicalize_name(req.name).replace("-", "_")
    provided = _provided if _provided is not None else md.packages_distributions()
    others = sorted({d for d in provided.get(module, []) if canonicalize_name(d) != canonicalize_name(req.name)})
    for name in others:
        version = installed_version(name)
        if version is not None:
            ok = not req.specifier or req.specifier.contains(version, prereleases=True)
            return StandIn(str(req), module, name, version, ok)
    return None


def requirement_status(requirements: list[str] | tuple[str, ...]) -> tuple[list[tuple[str, str]], list[StandIn]]:
    """What this environment makes of an env's requirements.

    Args:
        requirements: PEP 508 requirement strings.

    Returns:
        ``(unmet, stand_ins)``: ``(requirement, why)`` for each requirement not satisfied here, and each one whose import
        name another installed distribution provides within its specifier (:func:`stand_in`).

    Raises:
        ManifestError: a requirement that is not valid PEP 508.
    """
    unmet: list[tuple[str, str]] = []
    stand_ins: list[StandIn] = []
    provided: dict[str, list[str]] | None = None
    for text in requirements:
        try:
            req = Requirement(text)
        except InvalidRequirement as e:
            raise ManifestError(f"Requirement {text!r} is not valid ({e}). Fix the repo's dependencies.") from None
        if req.marker is not None and not req.marker.evaluate():
            continue
        installed = installed_version(req.name)
        if installed is None:
            provided = md.packages_distributions() if provided is None else provided
            other = stand_in(req, _provided=provided)
            if other is not None and other.satisfies:
                stand_ins.append(other)
            else:
                unmet.append((text, "not installed" + (f"; {other.describe()}" if other is not None else "")))
            continue
        if req.specifier and not req.specifier.contains(installed, prereleases=True):
            unmet.append((text, f"installed {installed}"))
    return unmet, stand_ins


def unmet_requirements(requirements: list[str] | tuple[str, ...]) -> list[tuple[str, str]]:
    """The requirements this environment does not satisfy (a stand-in within the requirement's specifier satisfies it:
    see :func:`requirement_status`).

    Args:
        requirements: PEP 508 requirement strings.

    Returns:
        ``(requirement, why)`` for each.

    Raises:
        ManifestError: a requirement that is not valid PEP 508.
    """
    return requirement_status(requirements)[0]


def check_requirements(requirements, *, repo: str) -> None:
    """Raise :class:`MissingRequirementsError` listing every unmet requirement with the pip line; warn
    (:class:`~hub_envs.errors.RequirementStandInWarning`) of each requirement another distribution stands in for.

    Args:
        requirements: the repo's requirement strings (PEP 508).
        repo: what the messages name (``user/name@sha``, or a folder).

    Raises:
        MissingRequirementsError: a requirement is not installed, or installed at a version outside its specifier.
    """
    unmet, stand_ins = requirement_status(requirements)
    for other in stand_ins:
        warnings.warn(
            f"{repo} requires {other.requirement}, which is not installed, but {other.describe()} (installed): "
            f"taken as standing in for it. Installing {Requirement(other.requirement).name} as well would write over "
            f"{other.distribution}'s files.",
            RequirementStandInWarning,
            stacklevel=3,
        )
    if unmet:
        lines = "\n".join(f"  {req:<30} {why}" for req, why in unmet)
        # a requirement whose import name another distribution provides: installing it would write over that one
        clash = [req for req, why in unmet if "comes from" in why]
        rest = [req for req, _ in unmet if req not in clash]
        advice = ""
        if rest:
            advice += (
                f"Install them (hub-envs never installs anything itself):\n  pip install {' '.join(shlex.quote(r) for r in rest)}"
            )
        if clash:
            advice += (
                ("\n" if advice else "")
                + f"For {', '.join(clash)}: installing it would write over the files of the distribution that provides "
                f"its import name; upgrade that one to a version within the requirement (or ask the env's author)."
            )
        raise MissingRequirementsError(f"{repo} requires packages this environment does not have:\n{lines}\n{advice}")
