"""``hub-envs attestations``: a repo's reproduction attestations (merged and in open pull requests) as a matrix env
revision x stack -> verdict; exit 1 when a signature fails verification."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

from hub_envs.errors import ConfigError
from hub_envs.repo.attestations import collect_attestations, matrix_text, verify_signature
from hub_envs.repo.refs import parse_repo_ref


@dataclass
class Config:
    """List a repo's reproduction attestations (merged and in open pull requests) as a matrix."""

    repo_id: str | None = None  # the env repo: user/name (every revision is listed); may come first, without the flag
    verify: bool = False  # check each signature with ssh-keygen -Y verify against --allowed_signers
    allowed_signers: Path | None = None  # with --verify: who may sign, in ssh-keygen's format ('principal key-type key')
    json: bool = False  # print the attestations as JSON instead of the matrix


def main(config: Config) -> int:
    """List the attestations of ``config.repo_id`` (with ``--verify``: each signature checked against ``--allowed_signers``).

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0; 1 when a signature fails verification.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    if config.repo_id is None:
        raise ConfigError("hub-envs attestations needs --repo_id=user/name.")
    if config.verify and config.allowed_signers is None:
        raise ConfigError("--verify=true needs --allowed_signers=FILE (ssh-keygen's format: 'principal key-type key').")
    repo_id, rev = parse_repo_ref(config.repo_id)
    if rev is not None:
        raise ConfigError(f"hub-envs attestations lists every revision: pass --repo_id={repo_id} without '@{rev}'.")
    entries = collect_attestations(repo_id)
    verified: dict[int, tuple[bool, str]] = {}
    if config.verify:
        for i, e in enumerate(entries):
            if e.signature is not None:
                verified[i] = verify_signature(e.data, e.signature, config.allowed_signers)  # type: ignore[arg-type]
    if config.json:
        print(
            json.dumps(
                [
                    {
                        "path": e.path,
                        "where": e.where,
                        "pr_num": e.pr_num,
                        "author": e.author,  # who opened the pull request it came from, as the Hub says
                        "merged_from": e.merged_from,
                        "revision": e.revision,
                        "error": e.error,
                        "signed": e.signature is not None,
                        "signature": (None if i not in verified else {"ok": verified[i][0], "detail": verified[i][1]}),
                        "attestation": e.attestation.to_dict() if e.attestation is not None else None,
                    }
                    for i, e in enumerate(entries)
                ],
                indent=2,
            )
        )
    else:
        print(f"Reproduction attestations of {repo_id}:\n")
        print(matrix_text(entries, verified if config.verify else None))
    failed = [i for i, (ok, _) in verified.items() if not ok]
    if failed:
        print(f"\n{len(failed)} signature(s) failed verification.", file=sys.stderr)
        return 1
    return 0
