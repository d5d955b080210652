"""LeRobot plugin (discovered by name on LeRobot >= 0.5): hub env repos in LeRobot's own CLIs.

    lerobot-eval --env.type=hub --env.repo_id=user/name --env.revision=<sha> --env.trust_remote_code=true \\
        --policy.path=outputs/train/.../pretrained_model --eval.n_episodes=10

Importing it does what ``--env.discover_packages_path=hub_envs.lerobot_plugin`` does: registers the
``hub`` env choice, routes hub env configs through hub-envs in ``lerobot_train`` / ``lerobot_eval``,
and pre-loads a per-repo choice named on the command line (see :mod:`hub_envs.lerobot_plugin`).
"""

import hub_envs.lerobot_plugin  # noqa: F401
