"""What the server knows of the repos hub-envs publishes: the file that makes a repo an env repo.

Written here, not imported from the client side (``hub_envs.repo.format``): the server imports no client
module. ``tests/test_adversarial_server.py`` checks the two agree.
"""

from __future__ import annotations

#: An env repo has this manifest at its root (``hub_envs.repo.format.MANIFEST_FILE``).
ENV_MANIFEST = "hub_env.json"
#: A benchmark suite's tasks in that manifest (``hub_envs.repo.format.Manifest.tasks``): objects with ``task``,
#: ``task_index``, ``instruction``, ``episodes``, ``fingerprint``; its ``benchmarks`` name their ``task``.
MANIFEST_TASKS = "tasks"
