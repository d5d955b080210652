"""``hub-envs eval <lerobot-eval flags>``: LeRobot's eval loop with a hub env (``--env.type=hub --env.repo_id=...``),
provenance written into its ``eval_info.json``. LeRobot parses the flags."""

from __future__ import annotations

ARGV = True  # main(argv): LeRobot's parser reads the flags


def main(argv: list[str]) -> int:
    """Run LeRobot's ``lerobot-eval`` with ``argv`` (a hub env chosen by ``--env.type=hub --env.repo_id=...``).

    Args:
        argv: the command's arguments.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    from hub_envs.lerobot.bridge import run_eval  # heavy: lerobot, torch (LeRobot parses the flags)

    return run_eval(argv)
