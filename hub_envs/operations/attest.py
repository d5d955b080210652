"""``attest``: publish a reproduction's verdict on the env's repo through a pull request, so anyone can attest and the
owner merges (the record: :mod:`hub_envs.repo.attestations`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from huggingface_hub import CommitOperationAdd

from hub_envs._compat import lfs_instead_of_xet
from hub_envs._text import safe_text
from hub_envs.errors import AttestationError, ConfigError
from hub_envs.repo import hub_io
from hub_envs.repo.attestations import SIGNATURE_SUFFIX, Attestation, sign_file
from hub_envs.repo.format import Manifest

__all__ = ["attest", "AttestResult"]


@dataclass(frozen=True)
class AttestResult:
    """What :func:`attest` published: the attestation, its path, the pull request."""

    attestation: Attestation
    path: str
    signed: bool
    pr_url: str
    pr_num: int
    commit: str

    def summary(self) -> str:
        """What was attested, and the pull request that adds it (what ``hub-envs reproduce --attest`` prints)."""
        done, of = self.attestation.tasks_reproduced
        return (
            f"Attested {self.attestation.verdict}{f' ({done} of {of} tasks)' if of else ''} for "
            f"{self.attestation.repo_id}@{self.attestation.sha[:12]} "
            f"(stack {self.attestation.stack_digest}{', signed' if self.signed else ''}): pull request #{self.pr_num} "
            f"adds {self.path}\n  {safe_text(self.pr_url)}\n  The repo's owner merges it: "
            f"huggingface_hub.HfApi().merge_pull_request({self.attestation.repo_id!r}, {self.pr_num})"
        )


def _whoami(token: str | None) -> str | None:
    try:
        return str(hub_io.api(token).whoami().get("name")) or None
    except Exception:  # noqa: BLE001 - anonymous: the PR would be refused anyway, with the Hub's message
        return None


def attest(
    report: Any,
    *,
    command: list[str] | tuple[str, ...],
    sign_key: str | Path | None = None,
    requirements: tuple[str, ...] | list[str] | None = None,
    token: str | None = None,
) -> AttestResult:
    """Publish the attestation of a reproduction on the env repo through a pull request (``create_commit(create_pr=True)``):
    anyone may open one on a public repo; its owner merges it.

    Args:
        report: a :class:`~hub_envs.harness.report.ReproduceReport` of a Hub repo (its written ``report.json`` is
            hashed into the attestation).
        command: the command line that reproduces it (``hub-envs reproduce ... --revision=<sha>``).
        sign_key: an OpenSSH private key: the signature goes next to the file (``.json.sig``).
        requirements: the env's requirements (None: read from the repo's manifest at the reproduced commit).
        token: the Hub token.

    Returns:
        The :class:`AttestResult`: the attestation, its path and the pull request.

    Raises:
        ConfigError: the reproduction was of a local folder (an attestation names a Hub repo and commit).
        AttestationError: the Hub opened no pull request.
        HubAccessError, HubError: the Hub refused the pull request.
    """
    if report.settings.get("source") == "folder":
        raise ConfigError(
            f"{report.repo_id} was reproduced from a local folder: an attestation names a Hub repo and commit. "
            "Reproduce --repo_id=user/name@<sha> to attest."
        )
    if requirements is None:
        requirements = Manifest.from_json(hub_io.read_manifest_text(report.repo_id, report.sha, token=token)).requirements
    att = Attestation.from_report(report, requirements=requirements, command=command, attested_by=_whoami(token))
    data = att.to_json().encode("utf-8")
    ops = [CommitOperationAdd(path_in_repo=att.path, path_or_fileobj=data)]
    if sign_key is not None:
        ops.append(CommitOperationAdd(path_in_repo=att.path + SIGNATURE_SUFFIX, path_or_fileobj=sign_file(data, sign_key)))
    client = hub_io.api(token)
    with hub_io.translate_hub_errors(report.repo_id, "main"), lfs_instead_of_xet(True):
        info = client.create_commit(
            report.repo_id,
            operations=ops,
            commit_message=f"Reproduction attestation: {att.verdict} at {att.sha[:12]} (stack {att.stack_digest})",
            commit_description=f"{att.summary()}\n\nCommand: {' '.join(att.command)}\nReport sha256: {att.report_sha256}",
            repo_type=hub_io.REPO_TYPE,
            create_pr=True,
        )
    if info.pr_url is None or info.pr_num is None:
        raise AttestationError(f"{report.repo_id}: the Hub did not open a pull request for {att.path}; nothing to merge.")
    return AttestResult(att, att.path, sign_key is not None, str(info.pr_url), int(info.pr_num), info.oid)
