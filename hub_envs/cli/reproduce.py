"""``hub-envs reproduce``: replay a repo's dataset and re-run its benchmarks; write JSON, Markdown and a plot; exit 0
when everything reproduces, 1 when anything diverged or failed."""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path

from hub_envs.cli.flags import EnvFlags, code_run
from hub_envs.errors import ConfigError
from hub_envs.repo import hub_io
from hub_envs.repo.refs import parse_repo_ref


@dataclass
class Config(EnvFlags):
    """Replay a repo's dataset and re-run its benchmarks; write JSON, Markdown and a plot."""

    trust_policy_code: bool = False  # consent to the LeRobot policy checkpoints the benchmarks name (other repos)
    workers: int = 0  # 0: up to 2 processes (local), the cluster's CPUs (ray)
    backend: str = "local"  # where the episodes run: local (this machine's processes) or ray (a Ray cluster)
    ray_address: str | None = None  # --backend=ray: the cluster; default $RAY_ADDRESS, else a local Ray for the run
    tolerance: float = 0.0  # largest absolute difference accepted in the replay (0: exact)
    out: Path | None = None  # default reproduce-out/<user>/<name>/
    replay: bool = True  # replay the dataset's recorded actions and compare every step with what was recorded
    benchmarks: bool = True  # re-run the benchmarks the repo declares and compare their metrics (with CIs)
    resamples: int = 1000  # bootstrap resamples of the benchmark confidence intervals
    json: bool = False  # also print the JSON report to stdout
    attest: bool = False  # publish the outcome as reproductions/<date>-<sha12>-<stack>.json through a pull request on the repo
    sign_key: Path | None = None  # with --attest: sign it with this OpenSSH private key (ssh-keygen -Y sign)


def main(config: Config) -> int:
    """Reproduce ``config.repo_id``, print the summary (or the JSON) and, with ``--attest``, publish the attestation.

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0 when everything reproduced, 1 when anything diverged or failed.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    from hub_envs.operations.attest import attest  # heavy: the operations import lerobot, torch
    from hub_envs.operations.reproduce import reproduce  # heavy: lerobot, torch

    if config.repo_id is None:
        raise ConfigError("hub-envs reproduce needs --repo_id=user/name (optionally --revision=<sha>).")
    if config.sign_key is not None and not config.attest:
        raise ConfigError("--sign_key signs an attestation: add --attest=true (or drop --sign_key).")
    if config.sign_key is not None and not Path(config.sign_key).expanduser().is_file():
        raise ConfigError(f"--sign_key={config.sign_key}: no such file; pass an OpenSSH private key. Nothing was run.")
    if config.attest:  # the pull request comes last: a Hub that will refuse it says so before anything runs
        hub_io.check_write_access(parse_repo_ref(config.repo_id)[0], pull_request=True)
    report = reproduce(
        config.repo_id,
        revision=config.revision,
        trust_remote_code=config.trust_remote_code,
        workers=config.workers or None,
        tolerance=config.tolerance,
        out=config.out,
        replay=config.replay,
        benchmarks=config.benchmarks,
        resamples=config.resamples,
        trust_policy_code=config.trust_policy_code,
        backend=config.backend,
        ray_address=config.ray_address,
        **code_run(config),
    )
    if config.json:
        print(report.to_json(), end="")
    else:
        print(report.summary())
    where = report.paths
    print(
        f"Reports: {where.get('markdown')} (people), {where.get('json')} (machines)"
        + (f", {where['png']} (plot)" if where.get("png") else ""),
        file=sys.stderr if config.json else sys.stdout,
    )
    if config.attest:
        result = attest(report, command=command_line(config, report.sha), sign_key=config.sign_key)
        print(result.summary(), file=sys.stderr if config.json else sys.stdout)
    return 0 if report.reproduced else 1


def command_line(config: Config, sha: str) -> list[str]:
    """The ``hub-envs reproduce`` command that re-runs a reproduction: the flags that differ from their defaults, the
    revision pinned to the commit that was reproduced (``--attest``/``--sign_key``/``--json``/``--out`` left out).

    >>> command_line(Config(repo_id="u/e", trust_remote_code=True, attest=True), "ab" * 20)[2:]
    ['--repo_id=u/e', '--revision=abababababababababababababababababababab', '--trust_remote_code=true']
    """
    out = ["hub-envs", "reproduce", f"--repo_id={config.repo_id.split('@')[0] if config.repo_id else ''}", f"--revision={sha}"]
    for f in dataclasses.fields(config):
        if f.name in ("repo_id", "revision", "attest", "sign_key", "json", "out"):
            continue
        value = getattr(config, f.name)
        if value != f.default:
            out.append(f"--{f.name}={str(value).lower() if isinstance(value, bool) else value}")
    return out
