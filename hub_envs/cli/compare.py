"""``hub-envs compare``: evaluate policies on the same seeds; report rates and returns with CIs and the seed-paired
difference."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from hub_envs.cli.flags import EnvFlags, code_run
from hub_envs.errors import ConfigError


@dataclass
class Config(EnvFlags):
    """Evaluate policies on the same seeds; report rates and returns with CIs and the seed-paired difference."""

    policies: str | None = None  # comma-separated: random, a pretrained_model folder, a Hub repo id
    against: str | None = None  # another revision (user/name@<sha>): each policy on both, paired seed by seed
    episodes: int = 20  # episodes per policy (and per revision); episode i resets with seed + i
    seed: int = 0  # the first episode's seed, and the bootstrap's
    trust_policy_code: bool = False  # consent to load Hub checkpoints (other repos than the env)
    workers: int = 0  # 0: up to 2 processes
    resamples: int = 1000  # bootstrap resamples of the confidence intervals
    out: Path | None = None  # default compare-out/<user>/<name>/
    backend: str = "local"  # where the episodes run: local (this machine's processes) or ray (a Ray cluster)
    ray_address: str | None = None  # --backend=ray: the cluster; default $RAY_ADDRESS, else a local Ray for the run
    json: bool = False  # print the JSON report to stdout instead of the summary
    task: str | None = None  # a benchmark suite: the task(s) to compare on, comma-separated (default: all, and pooled)


def main(config: Config) -> int:
    """Compare ``config.policies`` on ``config.repo_id`` (and ``config.against``), print the summary and where the reports are.

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    from hub_envs.operations.compare import compare  # heavy: lerobot, torch (after the flags are parsed)

    if config.repo_id is None or not config.policies:
        raise ConfigError(
            "hub-envs compare needs --repo_id=user/name@<sha> and --policies=A,B (random, a folder, a repo id), or "
            "--policies=A --against=user/name@<other sha> to compare two revisions."
        )
    report = compare(
        config.repo_id,
        [p for p in config.policies.split(",") if p.strip()],
        against=config.against,
        episodes=config.episodes,
        seed=config.seed,
        revision=config.revision,
        trust_remote_code=config.trust_remote_code,
        trust_policy_code=config.trust_policy_code,
        workers=config.workers or None,
        resamples=config.resamples,
        out=config.out,
        backend=config.backend,
        ray_address=config.ray_address,
        task=config.task,
        **code_run(config),
    )
    if config.json:
        print(report.to_json(), end="")
    else:
        print(report.summary())
    print(
        f"Reports: {report.paths.get('markdown')} (people), {report.paths.get('json')} (machines)"
        + (f", {report.paths['png']} (plot)" if report.paths.get("png") else ""),
        file=sys.stderr if config.json else sys.stdout,
    )
    return 0
