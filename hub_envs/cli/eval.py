"""``hub-envs eval <lerobot-eval flags>``: LeRobot's eval loop with a hub env (``--env.type=hub --env.repo_id=...``),
provenance written into its ``eval_info.json``. LeRobot parses the flags."""

from __future__ import annotations

ARGV = True  # main(argv): LeRobot's parser reads the flags


def main(argv: list[str]) -> int:
    """Run LeRobot's ``lerobot-eval`` with ``argv``."""
    from hub_envs.lerobot.bridge import run_eval  # heavy: lerobot, torch (LeRobot parses the flags)

    return run_eval(argv)
