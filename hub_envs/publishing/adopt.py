"""``adopt``: publish a hub-envs repo from a plain LeRobot EnvHub repo, through push_env's pipeline: the source's files
unchanged under ``source/`` (pinned to its commit), the adapter hub-envs writes for its entry file (with the features,
time limit and task the audit found), ``adopted_from.json`` naming ``user/name@<sha>:<path>``; then a random-action
dataset, the checks and a card, as for any push. A source whose ``make_env`` returns a suite of several tasks becomes a
hub-envs suite named after it (``[tool.hub-envs] tasks``, one dataset holding every task).

Example:
    >>> from hub_envs import adopt                                                                   # doctest: +SKIP
    >>> adopt("someone/reach@<sha>", "me/reach", trust_remote_code=True)                             # doctest: +SKIP
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

from hub_envs._text import safe_text
from hub_envs.errors import EnvContractError, IntegrityError
from hub_envs.loading.audit import AuditCheck, AuditReport, audit
from hub_envs.loading.plain import (
    CONFIG_ENTRY_POINT,
    DEFAULT_EPISODE_LENGTH,
    ENV_ENTRY_POINT,
    code_folder_files,
    fetch_plain,
    parse_hub_path,
    render_adapter,
)
from hub_envs.publishing.push import PushResult, push_env
from hub_envs.repo.refs import check_repo_id

__all__ = ["ADOPTED_FROM_FILE", "adopt", "adopted_folder"]

#: The file of an adopted repo that names its source (in the manifest's file list, so hashed like the code).
ADOPTED_FROM_FILE = "adopted_from.json"
#: The audit checks an adoption needs to pass (the others are what adoption fixes, or push_env checks itself).
REQUIRED = ("requirements", "contract", "LeRobot observation names", "the same features for every task")


def suite_shape_problems(report: AuditReport) -> list[AuditCheck]:
    """What keeps a suite from being adopted with the same suite name and task ids LeRobot's ``make_env`` gives on the
    source: a hub-envs suite is one suite whose task ids are ``0..N-1`` in order (its tasks' ``task_index``).

    Args:
        report: the source's audit.

    Returns:
        A failed :class:`~hub_envs.loading.audit.AuditCheck` per problem (none for one env).
    """
    if not report.tasks:
        return []
    problems = []
    suites = list(dict.fromkeys(str(t.suite) for t in report.tasks))
    if len(suites) > 1:
        problems.append(
            AuditCheck(
                "one suite",
                False,
                f"make_env returns {len(suites)} suites ({', '.join(suites)}); an adopted repo is one suite. Adopt an entry "
                f"file that returns one of them (user/name@rev:path/to/file.py).",
            )
        )
    ids = [t.task_id for t in report.tasks]
    if ids != list(range(len(ids))):
        problems.append(
            AuditCheck(
                "task ids",
                False,
                f"the task ids are {ids[:8]}; an adopted suite numbers its tasks 0..{len(ids) - 1} in order, as LeRobot's "
                f"LIBERO and Meta-World suites do, so its make_env would not give the same ids.",
            )
        )
    return problems


def adopted_folder(from_repo: str, folder: Path, report: AuditReport, *, token: str | None = None) -> Path:
    """Write the env folder push_env publishes for a plain repo: ``source/`` (its files at the audited commit),
    the adapter, ``adopted_from.json`` and ``pyproject.toml``.

    Args:
        from_repo: the audited reference (``report.source``: ``user/name@<sha>[:path]``).
        folder: an empty folder to write into.
        report: the source's audit (features, time limit, task).
        token: the Hub token.

    Returns:
        ``folder``.

    Raises:
        IntegrityError: the commit now holds other files than the audit ran (and consent covered): the endpoint served
            other content under the same commit id, or the cache changed.
    """
    ref = parse_hub_path(from_repo)
    src = fetch_plain(ref, token=token)  # fetched again: held to the digest of what the audit ran, with consent
    if report.content_digest is None or src.digest != report.content_digest:
        raise IntegrityError(
            f"{src.where}: its files now have content digest {src.digest[:16]}…, not {str(report.content_digest)[:16]}… "
            f"as when it was audited (and its code run, with consent): the endpoint serves other files under the same "
            f"commit id, or the cache changed. Nothing was published; adopt again, and check what it holds."
        )
    folder.mkdir(parents=True, exist_ok=True)
    for rel, data in code_folder_files(src, {}).items():  # each file's bytes checked against its hash as they are copied
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_bytes(data)
    features = {k: (t, tuple(s)) for k, (t, s) in report.features.items()}
    lengths = [t.episode_length or DEFAULT_EPISODE_LENGTH for t in report.tasks] or [
        report.episode_length or DEFAULT_EPISODE_LENGTH
    ]
    adapter = render_adapter(
        ref.text(src.sha),
        ref.entry,
        features=features,
        features_map=report.features_map,
        task=report.task,  # a suite's: its first task's name
        episode_length=max(lengths),  # a task's own time limit ends its episodes first
    )
    for name, data in adapter.items():
        (folder / name).write_bytes(data)
    origin = {"repo_id": ref.repo, "revision": src.sha, "entry": ref.entry, "source": ref.text(src.sha), "files": src.files}
    if report.tasks:  # where each task of the adopted suite sits in the source's make_env
        origin["tasks"] = [{"task": t.task, "suite": str(t.suite), "task_id": t.task_id} for t in report.tasks]
    (folder / ADOPTED_FROM_FILE).write_text(json.dumps(origin, indent=2, sort_keys=True) + "\n")
    name = ref.repo.split("/")[1] + (f"-{Path(ref.entry).stem}" if ref.explicit_entry else "")
    tasks = ""
    if report.tasks:  # a suite: its name is the manifest's, which the adopted env.py gives LeRobot as the suite's
        name = str(report.tasks[0].suite)
        tasks = f"tasks = [{', '.join(_toml_string(t.task) for t in report.tasks)}]\n"
    deps = ", ".join(_toml_string(r) for r in src.requirements)
    description = f"Adopted from the plain LeRobot EnvHub repo {ref.text(src.sha)} (its files unchanged in source/)."
    (folder / "pyproject.toml").write_text(
        f'[project]\nname = {_toml_string(name)}\nversion = "0.0.0"\n'
        f"description = {_toml_string(description)}\n"
        f"dependencies = [{deps}]\n\n"
        f"[tool.hub-envs]\nenv = {_toml_string(ENV_ENTRY_POINT)}\nconfig = {_toml_string(CONFIG_ENTRY_POINT)}\n{tasks}",
        encoding="utf-8",
    )
    return folder


def _toml_string(text: str) -> str:
    """``text`` as a TOML basic string: JSON's escapes but not its ``\\uD83D\\uDE00`` surrogate pairs, which TOML refuses
    (an entry file or a requirement marker outside the BMP made an unreadable pyproject.toml: red-team, session 29)."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def adopt(
    from_repo: str,
    repo_id: str,
    *,
    revision: str | None = None,
    trust_remote_code: bool = False,
    token: str | None = None,
    audit_output: str | Path | None = None,
    **push_options: Any,
) -> PushResult:
    """Publish ``repo_id`` as a hub-envs repo made from the plain LeRobot EnvHub repo ``from_repo``. The stages: audit the
    source (:func:`hub_envs.loading.audit.audit`: its code runs, with consent), write the env folder
    (:func:`adopted_folder`: code pinned to the audited commit), then push_env (checks, dataset, card, one commit).

    Args:
        from_repo: ``user/name[@rev][:path]``; a branch or tag is resolved to a commit once, and that commit is adopted.
        repo_id: the hub-envs repo to publish (``me/name``).
        revision: overrides ``@rev``.
        trust_remote_code: consent to run the source's code (else the trust list must hold it).
        token: the Hub token.
        audit_output: a file for the audit's JSON report.
        push_options: :func:`hub_envs.push_env`'s keywords (``episodes``, ``seed``, ``private``, ``progress``...).

    Returns:
        push_env's :class:`~hub_envs.publishing.push.PushResult`.

    Raises:
        EnvContractError: the audit found what adoption cannot fix (its contract, LeRobot's observation names, unmet
            requirements; a suite: any task's, features that differ between tasks, several suites, task ids other than
            ``0..N-1``); the message lists them.
        UntrustedCodeError: no consent to run the source's code.
        IntegrityError: the source commit's files changed between the audit and the copy (:func:`adopted_folder`).
        HubEnvsError: what push_env raises (a check failed, no write access...).
    """
    check_repo_id(repo_id, what="--repo_id")
    report = audit(from_repo, revision=revision, trust_remote_code=trust_remote_code, token=token, output=audit_output)
    blocking = [c for c in report.checks if c.name in REQUIRED and not c.passed]
    blocking += [
        AuditCheck(f"task {t.task!r}: {c.name}", c.passed, c.detail)
        for t in report.tasks
        for c in t.checks
        if c.name in REQUIRED and not c.passed
    ]
    blocking += suite_shape_problems(report)
    if blocking:
        raise EnvContractError(
            f"{report.source} cannot be adopted as it is:\n"
            + "\n".join(f"  {c.name}: {c.detail}" for c in blocking)
            + "\nFix the source repo (or install its requirements) and adopt again; `hub-envs audit` shows every check."
        )
    with tempfile.TemporaryDirectory(prefix="hub-envs-adopt-") as tmp:
        folder = adopted_folder(report.source, Path(tmp) / safe_text(repo_id.split("/")[1]), report, token=token)
        return push_env(
            folder,
            repo_id,
            token=token,
            commit_message=push_options.pop("commit_message", None) or f"Adopt {report.source}",
            **push_options,
        )
