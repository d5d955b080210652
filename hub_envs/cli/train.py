"""``hub-envs train <lerobot-train flags>``: LeRobot's training loop with a hub env (``--env.type=hub
--env.repo_id=...``), provenance written beside the checkpoints. LeRobot parses the flags."""

from __future__ import annotations

from hub_envs._compat import lerobot_pipeline_flags
from hub_envs.cli.argv import check_flags

ARGV = True  # main(argv, prog): LeRobot's parser reads the flags


def main(argv: list[str], prog: str = "hub-envs train") -> int:
    """Run LeRobot's ``lerobot-train`` with ``argv`` (a hub env chosen by ``--env.type=hub --env.repo_id=...``); a top-level
    flag lerobot-train does not have is refused before LeRobot (and torch) is imported.

    Args:
        argv: the command's arguments.
        prog: how messages name the command.

    Returns:
        The exit code: 0.

    Raises:
        UsageError: a flag lerobot-train does not have (its nested flags, ``--policy.<x>``, are LeRobot's parser's to judge).
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    known = lerobot_pipeline_flags("train")
    if known is not None:  # else LeRobot's parser judges them all
        check_flags(prog, argv, known, nested=True)
    from hub_envs.lerobot.bridge import run_train  # heavy: lerobot, torch (LeRobot parses the flags)

    return run_train(argv)
