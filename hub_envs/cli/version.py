"""``hub-envs --version`` (``-V``): hub-envs' version and the stack it runs on, as LeRobot's ``lerobot-info`` prints
it (to paste into an issue); every version read from the installed metadata, no package imported."""

from __future__ import annotations

import platform
import shutil
import subprocess

from hub_envs._stack import PACKAGES, installed_version
from hub_envs._version import __version__

#: the distributions ``--version`` names: the stack an env runs on, then what the extras add (Ray, video)
STACK = (*PACKAGES, "ray", "datasets", "av", "torchcodec")


def version_text() -> str:
    """What ``hub-envs --version`` prints: ``hub-envs <version>``, then one ``- name: version`` line per part of the stack.

    Returns:
        The text (``not installed`` for a package that is not; ffmpeg's ``N/A`` when it is not on the PATH).

    >>> version_text().splitlines()[0] == f"hub-envs {__version__}"
    True
    """
    lines = [
        f"hub-envs {__version__}",
        f"- python: {platform.python_version()} ({platform.python_implementation()})",
        f"- platform: {platform.platform()}",
        *(f"- {name}: {installed_version(name) or 'not installed'}" for name in STACK),
        f"- ffmpeg: {ffmpeg_version()}",
    ]
    return "\n".join(lines)


def ffmpeg_version() -> str:
    """The version of the ``ffmpeg`` on the PATH (LeRobot's video encoding falls back to it), as ``lerobot-info`` reads it.

    Returns:
        Its version, or ``N/A`` when there is none, or what went wrong reading it.
    """
    path = shutil.which("ffmpeg")
    if path is None:
        return "N/A"
    try:
        out = subprocess.run([path, "-version"], capture_output=True, text=True, timeout=10, check=True)
        return out.stdout.splitlines()[0].split(" ")[2]
    except (OSError, subprocess.SubprocessError, IndexError):
        return "installed (its version could not be read)"
