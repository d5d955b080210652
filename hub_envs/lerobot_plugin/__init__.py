"""Hub envs in LeRobot's own CLIs, through LeRobot's plugin flag ``--env.discover_packages_path``.

    lerobot-eval --env.discover_packages_path=hub_envs.lerobot_plugin \\
        --env.type=hub --env.repo_id=user/pendulum-lerobot --env.revision=<sha> --env.trust_remote_code=true \\
        --policy.path=outputs/train/.../pretrained_model --eval.n_episodes=10 --eval.batch_size=10

LeRobot's ``parser.wrap`` imports this package before it parses the other flags. Importing it
registers the ``hub`` env choice, routes ``lerobot_train`` / ``lerobot_eval`` env creation and env
processors for hub env configs through :mod:`hub_envs.lerobot.env`, and, for a per-repo choice
(``--env.type=user/name@<sha12>``), loads that repo so the choice exists (trust it with
``hub-envs trust user/name@<sha>``, ``--env.trust_remote_code=true`` as for ``hub``, or lerobot-eval's ``--trust_remote_code=true``).
``hub-envs train`` / ``hub-envs eval`` do the same and also write provenance next to the results.
"""

from __future__ import annotations

import sys

import hub_envs.repo.hub_io  # noqa: F401  (its endpoint check is on huggingface_hub's client before LeRobot downloads)
from hub_envs.lerobot.bridge import prepare_argv

prepare_argv(sys.argv[1:], command="plugin")
