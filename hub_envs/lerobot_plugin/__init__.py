"""Hub envs in LeRobot's own CLIs (``lerobot-eval --env.discover_packages_path=hub_envs.lerobot_plugin --env.type=hub ...``):
importing it registers the ``hub`` choice and routes LeRobot's env creation through :mod:`hub_envs.lerobot.env`.
"""

from __future__ import annotations

import sys

import hub_envs.repo.hub_io  # noqa: F401  (its endpoint check is on huggingface_hub's client before LeRobot downloads)
from hub_envs.lerobot.bridge import prepare_argv

prepare_argv(sys.argv[1:], command="plugin")
