"""Hub envs inside LeRobot's own runtime: its env configs, ``make_env``, train and eval.

- :mod:`~hub_envs.lerobot.env`: the ``--env.type=hub`` choice, LeRobot-ready vector envs, LeRobot's hooks.
- :mod:`~hub_envs.lerobot.bridge`: ``hub-envs train`` / ``hub-envs eval`` (LeRobot's scripts, provenance beside).

LeRobot's ``--env.discover_packages_path`` imports :mod:`hub_envs.lerobot_plugin`, which stays at that path.
This package sits on top of :func:`hub_envs.load_env`; nothing below it imports it.
"""
