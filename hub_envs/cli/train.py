"""``hub-envs train <lerobot-train flags>``: LeRobot's training loop with a hub env (``--env.type=hub
--env.repo_id=...``), provenance written beside the checkpoints. LeRobot parses the flags."""

from __future__ import annotations

ARGV = True  # main(argv): LeRobot's parser reads the flags


def main(argv: list[str]) -> int:
    """Run LeRobot's ``lerobot-train`` with ``argv``."""
    from hub_envs.lerobot.bridge import run_train  # heavy: lerobot, torch (LeRobot parses the flags)

    return run_train(argv)
