"""``hub-envs diff``: what changed between two revisions of an env repo (or two repos), and does it behave
differently? Exit 0: identical behaviour; 1: behaviour differs; 2: error (the message says what to do)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from hub_envs.cli.flags import CodeFlags, code_run
from hub_envs.errors import ConfigError, HubEnvsError

POSITIONAL = ("old", "new")  # hub-envs diff user/name@A user/name@B


@dataclass
class Config(CodeFlags):
    """Compare two revisions of an env repo (or two repos): files, manifest, spaces, behaviour on the same seeds and actions."""

    old: str | None = None  # the old revision, user/name@A (pin shas); may come first, without the flag
    new: str | None = None  # the new one, user/name@B, or another repo; may come second, without the flag
    episodes: int = 2  # replay the old revision's recorded actions of this many dataset episodes on both
    random_episodes: int = 2  # plus this many seeded random-action episodes
    benchmarks: bool = True  # re-run the old revision's declared benchmarks on both: paired metric deltas with CIs
    trust_policy_code: bool = False  # consent to the LeRobot policy checkpoints those benchmarks name (other repos)
    resamples: int = 1000  # bootstrap resamples of the paired CIs
    tolerance: float = 0.0  # largest absolute difference still counted as identical (0: exact)
    workers: int = 1  # processes for the episodes (the report does not depend on it)
    out: Path | None = None  # default diff-out/<user>/<name>/
    json: bool = False  # print the JSON report to stdout instead of the summary


def main(config: Config) -> int:
    """Diff ``config.old`` and ``config.new``, print the summary (``--json=true``: the JSON report) and where the reports are.

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0: identical behaviour; 1: behaviour differs; 2: a hub-envs error (printed).

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    try:
        from hub_envs.operations.diff import diff  # heavy: gymnasium, lerobot (after the flags are parsed)

        if not config.old or not config.new:
            raise ConfigError("hub-envs diff needs --old=user/name@<sha> and --new=user/name@<sha> (or another repo).")
        report = diff(
            config.old,
            config.new,
            episodes=config.episodes,
            random_episodes=config.random_episodes,
            trust_remote_code=config.trust_remote_code,
            tolerance=config.tolerance,
            out=config.out,
            workers=config.workers,
            benchmarks=config.benchmarks,
            resamples=config.resamples,
            trust_policy_code=config.trust_policy_code,
            **code_run(config),
        )
    except HubEnvsError as e:
        print(f"error: {type(e).__name__}: {e}", file=sys.stderr)
        return 2
    print(report.to_json() if config.json else report.summary(), end="\n" if not config.json else "")
    where = report.paths
    print(
        f"Reports: {where.get('markdown')} (people), {where.get('json')} (machines)"
        + (f", {where['png']} (plot)" if where.get("png") else ""),
        file=sys.stderr if config.json else sys.stdout,
    )
    return report.exit_code
