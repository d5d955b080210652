"""``python -m hub_envs._stack``: one line naming the stack this interpreter runs (for make and CI logs).

Example:
    >>> from hub_envs._stack import describe
    >>> describe().startswith("python ")
    True
"""

from __future__ import annotations

import platform

from hub_envs.requirements import installed_version

PACKAGES = ("lerobot", "huggingface_hub", "draccus", "gymnasium", "numpy", "torch", "pybullet")


def describe() -> str:
    parts = [f"python {platform.python_version()}"]
    parts += [f"{name} {installed_version(name) or '-'}" for name in PACKAGES]
    return ", ".join(parts)


if __name__ == "__main__":
    print(describe())
