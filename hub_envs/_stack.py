"""The stack this interpreter runs: installed versions, the CPU, a requirement's dependency closure.

``python -m hub_envs._stack`` prints one line naming it (for make and CI logs).

Example:
    >>> from hub_envs._stack import describe, installed_version
    >>> describe().startswith("python "), installed_version("no-such-distribution")
    (True, None)
"""

from __future__ import annotations

import importlib.metadata as md
import platform
import subprocess

from packaging.requirements import InvalidRequirement, Requirement
from packaging.utils import canonicalize_name

PACKAGES = ("lerobot", "huggingface_hub", "draccus", "gymnasium", "numpy", "torch", "pybullet")
#: the packages every report records the versions of (what a rollout runs on besides the env's own requirements)
CORE_PACKAGES = ("numpy", "gymnasium", "lerobot", "torch", "huggingface_hub", "draccus", "hub-envs")


def installed_version(name: str) -> str | None:
    """The installed version of distribution ``name``.

    Same answer as ``importlib.metadata.version``, but reads only the header of METADATA: a long description makes
    parsing the whole file cost more, on every ``load_env``.

    Args:
        name: a distribution name (``"lerobot"``, ``"hub-envs"``).

    Returns:
        Its version string, or None when it is not installed.
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


def cpu_model() -> str:
    """The CPU's model name: ``/proc/cpuinfo`` on Linux, ``sysctl`` on macOS, else ``platform.processor()``.

    Returns:
        A human-readable model name (``"unknown"`` when nothing says).
    """
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith(("model name", "hardware", "cpu model")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    if platform.system() == "Darwin":
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
    """The installed version of every distribution ``requirements`` pull in, transitively, with environment markers
    and extras evaluated as pip would here: what ``versions="publisher"`` pins beyond the requirements themselves.

    Args:
        requirements: PEP 508 requirement strings (an unparsable one is skipped).
        also: more requirements, what an env worker needs itself.

    Returns:
        ``{canonical name: version}``, sorted; a requirement that is not installed is left out (the preflight
        reports it).
    """
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
            dist = md.distribution(name)
        except md.PackageNotFoundError:
            continue
        closure[name] = dist.version
        extras_seen.setdefault(name, set()).update(wanted)
        for text in dist.requires or ():
            try:
                pending.append((Requirement(text), frozenset(extras_seen[name])))
            except InvalidRequirement:
                continue
    return dict(sorted(closure.items()))


def describe() -> str:
    """One line: ``python 3.13.0, lerobot 0.6.1, huggingface_hub 1.3.3, ...`` (``-`` for a package not installed)."""
    parts = [f"python {platform.python_version()}"]
    parts += [f"{name} {installed_version(name) or '-'}" for name in PACKAGES]
    return ", ".join(parts)


if __name__ == "__main__":
    print(describe())
