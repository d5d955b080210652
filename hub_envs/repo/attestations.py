"""Reproduction attestations, the record: "this env, at this commit, reproduced (or not) on this stack", one JSON file
``reproductions/<date>-<commit sha12>-<stack digest>.json`` in the env's repo (typed and validated like the manifest),
its optional OpenSSH signature, and reading them back (merged, and in open pull requests).

Example:
    >>> from hub_envs.repo.attestations import stack_digest
    >>> stack_digest({"python": "3.13.1", "packages": {"numpy": "2.2.6"}})
    '19efa394d727'
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import json
import logging
import platform
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from huggingface_hub import hf_hub_download

from hub_envs._stack import CORE_PACKAGES, cpu_model, requirement_closure
from hub_envs._text import safe_text
from hub_envs.errors import AttestationError, HostileResponseError, HubError
from hub_envs.repo import hub_io
from hub_envs.repo.format import REPRODUCTIONS_DIR, is_attestation_file
from hub_envs.repo.refs import check_repo_id

logger = logging.getLogger(__name__)

__all__ = [
    "Attestation",
    "AttestationEntry",
    "FORMAT_VERSION",
    "REPRODUCTIONS_DIR",
    "collect_attestations",
    "merged_attestations",
    "sign_file",
    "stack_digest",
    "verify_signature",
    "describe_stack",
    "matrix_text",
]

#: The format this hub-envs writes; it reads every format from 1 up to this one. 2 added ``tasks`` (a benchmark suite's
#: verdict per task), written only for a suite (a one-task env's attestation stays 1, which older hub-envs read).
FORMAT_VERSION = 2
SINGLE_TASK_FORMAT_VERSION = 1
SUITE_FORMAT_VERSION = 2
KIND = "hub-envs reproduction attestation"
SIGNATURE_NAMESPACE = "hub-envs"
SIGNATURE_SUFFIX = ".sig"
VERDICTS = ("REPRODUCED", "NOT REPRODUCED")
_HEX40 = re.compile(r"^[0-9a-f]{40}$")
_HEX64 = re.compile(r"^[0-9a-f]{64}$")


def stack_digest(stack: dict[str, Any]) -> str:
    """12 hex digits naming a stack: the sha256 of its canonical JSON.

    Args:
        stack: a stack (:func:`current_stack`).

    Returns:
        The digest.
    """
    return hashlib.sha256(json.dumps(stack, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:12]


def current_stack(provenance: dict[str, Any], requirements: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """The stack a reproduction ran on: python, platform, CPU model, the packages it depends on (core, simulator, the env's
    requirement closure).

    Args:
        provenance: the report's (its ``versions_here`` honour a venv worker).
        requirements: the env's requirements (their closure is recorded).

    Returns:
        The stack, JSON-ready.
    """
    here = dict(provenance.get("versions_here") or {})
    python = here.pop("python", platform.python_version())
    simulator = {k: v for k, v in here.items() if k not in CORE_PACKAGES}
    return {
        "python": python,
        "implementation": platform.python_implementation(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "packages": {k: v for k, v in here.items() if k in CORE_PACKAGES},
        "simulator": simulator,
        "requirement_closure": requirement_closure(requirements),
    }


def describe_stack(stack: dict[str, Any]) -> str:
    """One line: ``python 3.13.1, lerobot 0.6.1, torch 2.11.0, numpy 2.2.6, pybullet 3.2.7 on Linux x86_64 (AMD EPYC)``.

    Args:
        stack: a stack (:func:`current_stack`).

    Returns:
        The line.
    """
    pk = stack.get("packages", {})
    parts = [f"python {stack.get('python')}"]
    parts += [f"{n} {pk[n]}" for n in ("lerobot", "torch", "numpy", "gymnasium") if n in pk]
    parts += [f"{n} {v}" for n, v in sorted(stack.get("simulator", {}).items())]
    system = str(stack.get("platform", "")).split("-")[0]
    return ", ".join(parts) + f" on {system} {stack.get('machine')} ({stack.get('cpu')})"


# --- the format ---------------------------------------------------------------------------------


def _replay_summary(replay: dict[str, Any] | None) -> dict[str, Any] | None:
    if replay is None:
        return None
    episodes = replay.get("episodes", [])
    diverged = [e for e in episodes if not e.get("ok")]
    first = None
    for e in diverged:
        if e.get("divergences"):
            d = e["divergences"][0]
            first = {"episode": e.get("episode"), "step": d.get("step"), "feature": d.get("feature")}
            break
    return {
        "ok": bool(replay.get("ok")),
        "episodes": len(episodes),
        "frames": sum(int(e.get("length", 0)) for e in episodes),
        "diverged": len(diverged),
        "tolerance": replay.get("tolerance"),
        "features": sorted(replay.get("features", {})),
        "first_divergence": first,
    }


def _benchmark_summary(b: dict[str, Any]) -> dict[str, Any]:
    keep = ("name", "published", "reproduced", "ci_low", "ci_high", "tolerance", "passed")
    return {
        "name": b.get("name"),
        "policy": b.get("policy"),
        "passed": bool(b.get("passed")),
        "error": b.get("error"),
        "episodes": len(b.get("seeds", [])),
        "seeds": list(b.get("seeds", [])),
        "confidence": b.get("confidence"),
        "resamples": b.get("resamples"),
        "metrics": [{k: m.get(k) for k in keep} for m in b.get("metrics", [])],
    }


def _task_summary(t: dict[str, Any]) -> dict[str, Any]:
    """A suite task's part of the attestation: its verdict, checks, replay, benchmarks and fingerprint."""
    return {
        "task": t.get("task"),
        "task_index": t.get("task_index"),
        "verdict": t.get("verdict"),
        "reproduced": bool(t.get("reproduced")),
        "checks": dict(t.get("checks") or {}),
        "replay": _replay_summary(t.get("replay")),
        "benchmarks": [_benchmark_summary(b) for b in t.get("benchmarks", [])],
        "fingerprint": {k: (t.get("fingerprint") or {}).get(k) for k in ("status", "ok", "digest")},
    }


def _check_tasks(tasks: Any, reproduced: bool, bad: Any) -> None:
    """A suite attestation's ``tasks``: distinct named tasks at their indices, each verdict agreeing with its own
    checks, and the attestation reproduced only when every task is."""
    if not isinstance(tasks, list) or not all(isinstance(t, dict) for t in tasks):
        raise bad("field 'tasks' must be a list of objects")
    names = [t.get("task") for t in tasks]
    if not all(isinstance(n, str) and 0 < len(n) <= 200 for n in names) or len(set(names)) != len(names):
        raise bad(f"field 'tasks' must name distinct tasks (strings of 1 to 200 characters), got {str(names)[:80]!r}")
    for i, t in enumerate(tasks):
        checks = t.get("checks")
        if not (
            type(t.get("task_index")) is int
            and t.get("verdict") in VERDICTS
            and isinstance(t.get("reproduced"), bool)
            and (t["verdict"] == "REPRODUCED") == t["reproduced"]
            and isinstance(checks, dict)
            and all(isinstance(v, bool) for v in checks.values())
            and t["reproduced"] == all(checks.values())
        ):
            raise bad(f"tasks[{i}] must hold a task_index, and a verdict agreeing with 'reproduced' and its 'checks'")
    if tasks and reproduced != all(t["reproduced"] for t in tasks):
        raise bad("'reproduced' contradicts 'tasks'")


@dataclass(frozen=True)
class Attestation:
    """One reproduction attestation: what ``reproductions/<date>-<commit sha12>-<stack digest>.json`` holds. Frozen."""

    repo_id: str
    sha: str
    content_digest: str
    dataset_fingerprint: str | None
    verdict: str
    reproduced: bool
    checks: dict[str, bool]
    replay: dict[str, Any] | None
    benchmarks: tuple[dict[str, Any], ...]
    fingerprint: dict[str, Any]
    stack: dict[str, Any]
    stack_digest: str
    hub_envs_version: str
    command: tuple[str, ...]
    report_sha256: str
    created_at: str
    attested_by: str | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    format_version: int = SINGLE_TASK_FORMAT_VERSION  # a suite's: SUITE_FORMAT_VERSION
    kind: str = KIND
    #: a benchmark suite's verdict per task (format 2): ``task``, ``task_index``, ``verdict``, ``reproduced``,
    #: ``checks``, ``replay``, ``benchmarks``, ``fingerprint``, in task-id order; empty for a one-task env
    tasks: tuple[dict[str, Any], ...] = ()

    @property
    def tasks_reproduced(self) -> tuple[int, int]:
        """``(tasks reproduced, tasks)`` of a suite; ``(0, 0)`` for a one-task env."""
        return sum(bool(t.get("reproduced")) for t in self.tasks), len(self.tasks)

    @property
    def path(self) -> str:
        """Where it goes in the env repo: ``reproductions/<date>-<commit sha12>-<stack digest>.json`` (the commit in
        the name: attesting another commit of the same content, on the same stack and day, adds a file, not replaces one).
        """
        return f"{REPRODUCTIONS_DIR}/{self.created_at[:10]}-{self.sha[:12]}-{self.stack_digest}.json"

    @classmethod
    def from_report(
        cls,
        report: Any,
        *,
        requirements: tuple[str, ...] | list[str] = (),
        command: list[str] | tuple[str, ...],
        attested_by: str | None = None,
    ) -> Attestation:
        """The attestation of a reproduction.

        Args:
            report: a :class:`hub_envs.harness.report.ReproduceReport` (its written ``report.json`` is hashed).
            requirements: the env's requirements.
            command: the command line that reproduces it.
            attested_by: the Hub account attesting (self-declared).

        Returns:
            The :class:`Attestation`, validated.
        """
        data = report.to_dict()
        written = report.paths.get("json") if getattr(report, "paths", None) else None
        raw = Path(written).read_bytes() if written and Path(written).is_file() else report.to_json().encode()
        prov = data.get("provenance", {})
        stack = current_stack(prov, requirements)
        now = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")
        return cls(
            repo_id=data["repo_id"],
            sha=data["sha"],
            content_digest=str(prov.get("content_digest", "")),
            dataset_fingerprint=prov.get("dataset_fingerprint"),
            verdict=data["verdict"],
            reproduced=bool(data["reproduced"]),
            checks=dict(data.get("checks", {})),
            replay=_replay_summary(data.get("replay")),
            benchmarks=tuple(_benchmark_summary(b) for b in data.get("benchmarks", [])),
            fingerprint={k: data.get("fingerprint", {}).get(k) for k in ("status", "ok", "digest")},
            stack=stack,
            stack_digest=stack_digest(stack),
            hub_envs_version=str(prov.get("hub_envs_version", "")),
            command=tuple(command),
            report_sha256=hashlib.sha256(raw).hexdigest(),
            created_at=now,
            attested_by=attested_by,
            settings={k: v for k, v in data.get("settings", {}).items() if k != "source"},
            tasks=tuple(_task_summary(t) for t in data.get("tasks", [])),
            format_version=SUITE_FORMAT_VERSION if data.get("tasks") else SINGLE_TASK_FORMAT_VERSION,
        ).validated()

    # -- (de)serialization --

    def to_dict(self) -> dict[str, Any]:
        """The attestation as JSON-ready data."""
        d = dataclasses.asdict(self)
        d["benchmarks"] = list(self.benchmarks)
        d["command"] = list(self.command)
        if self.format_version < SUITE_FORMAT_VERSION:
            del d["tasks"]  # format 1 has no such field: older hub-envs read the file
        else:
            d["tasks"] = list(self.tasks)
        return d

    def to_json(self) -> str:
        """Canonical JSON (sorted keys, fixed indentation): the bytes that are hashed and signed."""
        return json.dumps(self.to_dict(), indent=2, sort_keys=True, allow_nan=False) + "\n"

    def validated(self, *, where: str = "attestation") -> Attestation:
        """This attestation checked as every reader checks it.

        Args:
            where: names it in messages.

        Returns:
            It, read back from its own dict.

        Raises:
            AttestationError: a field that is not what the format allows.
        """
        return type(self).from_dict(self.to_dict(), where=where)

    @classmethod
    def from_json(cls, text: str | bytes, *, where: str = "attestation") -> Attestation:
        """Read an attestation file.

        Args:
            text: the file's text or bytes.
            where: names it in messages.

        Returns:
            The :class:`Attestation`.

        Raises:
            AttestationError: not JSON, or a field that is wrong.
        """
        try:
            data = json.loads(text)
        except (ValueError, RecursionError) as e:
            raise AttestationError(f"{where}: not valid JSON ({e}). Re-attest with hub-envs reproduce --attest=true.") from None
        return cls.from_dict(data, where=where)

    @classmethod
    def from_dict(cls, data: Any, *, where: str = "attestation") -> Attestation:
        """Read and check an attestation.

        Args:
            data: the decoded JSON.
            where: names it in messages.

        Returns:
            The :class:`Attestation`.

        Raises:
            AttestationError: naming the field that is wrong.
        """

        def bad(what: str) -> AttestationError:
            return AttestationError(f"{where}: {what}. Re-attest with `hub-envs reproduce --attest=true`.")

        if not isinstance(data, dict):
            raise bad(f"must be a JSON object, got {type(data).__name__}")
        if data.get("kind") != KIND:
            raise bad(f"'kind' is {str(data.get('kind'))[:60]!r}, not {KIND!r}")
        version = data.get("format_version")
        if type(version) is not int or not 1 <= version <= FORMAT_VERSION:
            raise bad(f"format_version {version!r} is not supported (this hub-envs reads 1 to {FORMAT_VERSION}; upgrade it)")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise bad(f"unknown field(s) {unknown}")
        required = {
            f.name
            for f in dataclasses.fields(cls)
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        }
        missing = sorted(required - set(data))
        if missing:
            raise bad(f"missing field(s) {missing}")
        checks: list[tuple[str, Any, bool]] = [
            ("repo_id", data["repo_id"], isinstance(data["repo_id"], str) and data["repo_id"].count("/") == 1),
            ("sha", data["sha"], isinstance(data["sha"], str) and bool(_HEX40.match(data["sha"]))),
            ("content_digest", data["content_digest"], isinstance(data["content_digest"], str)),
            (
                "dataset_fingerprint",
                data["dataset_fingerprint"],
                data["dataset_fingerprint"] is None or isinstance(data["dataset_fingerprint"], str),
            ),
            ("verdict", data["verdict"], data["verdict"] in VERDICTS),
            ("reproduced", data["reproduced"], isinstance(data["reproduced"], bool)),
            (
                "checks",
                data["checks"],
                isinstance(data["checks"], dict) and all(isinstance(v, bool) for v in data["checks"].values()),
            ),
            ("replay", data["replay"], data["replay"] is None or isinstance(data["replay"], dict)),
            (
                "benchmarks",
                data["benchmarks"],
                isinstance(data["benchmarks"], list) and all(isinstance(b, dict) for b in data["benchmarks"]),
            ),
            ("fingerprint", data["fingerprint"], isinstance(data["fingerprint"], dict)),
            ("stack", data["stack"], isinstance(data["stack"], dict) and isinstance(data["stack"].get("packages"), dict)),
            ("stack_digest", data["stack_digest"], isinstance(data["stack_digest"], str)),
            ("hub_envs_version", data["hub_envs_version"], isinstance(data["hub_envs_version"], str)),
            ("command", data["command"], isinstance(data["command"], list) and all(isinstance(c, str) for c in data["command"])),
            (
                "report_sha256",
                data["report_sha256"],
                isinstance(data["report_sha256"], str) and bool(_HEX64.match(data["report_sha256"])),
            ),
            (
                "created_at",
                data["created_at"],
                isinstance(data["created_at"], str) and bool(re.match(r"^\d{4}-\d{2}-\d{2}T", data["created_at"])),
            ),
            ("attested_by", data.get("attested_by"), data.get("attested_by") is None or isinstance(data.get("attested_by"), str)),
            ("settings", data.get("settings", {}), isinstance(data.get("settings", {}), dict)),
        ]
        for name, value, ok in checks:
            if not ok:
                raise bad(f"field {name!r} has an invalid value {str(value)[:80]!r}")
        if "tasks" in data and version < SUITE_FORMAT_VERSION:
            raise bad(f"field 'tasks' needs format_version {SUITE_FORMAT_VERSION}, the file says {version}")
        _check_tasks(data.get("tasks", []), data["reproduced"], bad)
        if (data["verdict"] == "REPRODUCED") != data["reproduced"]:
            raise bad(f"'verdict' {data['verdict']!r} contradicts 'reproduced' {data['reproduced']!r}")
        if data["reproduced"] != all(data["checks"].values()):
            raise bad("'reproduced' contradicts 'checks'")
        if stack_digest(data["stack"]) != data["stack_digest"]:
            raise bad(f"'stack_digest' {data['stack_digest']!r} is not the digest of 'stack' ({stack_digest(data['stack'])})")
        values = {k: data[k] for k in names if k in data}
        values["benchmarks"] = tuple(data["benchmarks"])
        values["command"] = tuple(data["command"])
        values["tasks"] = tuple(data.get("tasks", []))
        return cls(**values)

    # -- text --

    def summary(self) -> str:
        """One line: the verdict (a suite's: how many of its tasks), the env commit and the stack."""
        done, of = self.tasks_reproduced
        tasks = f" ({done} of {of} tasks)" if of else ""
        return f"{self.verdict}{tasks}: {self.repo_id}@{self.sha[:12]} on {describe_stack(self.stack)}"


# --- signatures (OpenSSH) -----------------------------------------------------------------------


def _ssh_keygen() -> str:
    exe = shutil.which("ssh-keygen")
    if exe is None:
        raise AttestationError(
            "ssh-keygen is not installed: signing and verifying attestations need OpenSSH's ssh-keygen "
            "(Debian/Ubuntu: apt-get install openssh-client; macOS has it)."
        )
    return exe


def sign_file(data: bytes, key: str | Path) -> bytes:
    """The OpenSSH signature (``ssh-keygen -Y sign -n hub-envs``) of ``data``.

    Args:
        data: the attestation file's bytes.
        key: an OpenSSH private key.

    Returns:
        The signature file's bytes.

    Raises:
        AttestationError: no such key, or ssh-keygen refused it.
    """
    key = Path(key).expanduser()
    if not key.is_file():
        raise AttestationError(f"--sign_key={key}: no such file. Pass an OpenSSH private key (e.g. ~/.ssh/id_ed25519).")
    with tempfile.TemporaryDirectory(prefix="hub-envs-sign-") as tmp:
        target = Path(tmp) / "attestation.json"
        target.write_bytes(data)
        out = subprocess.run(
            [_ssh_keygen(), "-Y", "sign", "-f", str(key), "-n", SIGNATURE_NAMESPACE, str(target)],
            capture_output=True,
            text=True,
            stdin=subprocess.DEVNULL,
            timeout=60,
        )
        sig = target.with_name(target.name + SIGNATURE_SUFFIX)
        if out.returncode != 0 or not sig.is_file():
            raise AttestationError(
                f"ssh-keygen could not sign with {key}: {out.stderr.strip() or out.stdout.strip()}. "
                "Pass an unencrypted OpenSSH private key, or one your ssh-agent holds."
            )
        return sig.read_bytes()


def verify_signature(data: bytes, signature: bytes, allowed_signers: str | Path) -> tuple[bool, str]:
    """Check a signature against an ``allowed_signers`` file (ssh-keygen's format: ``principal key-type key``).

    Args:
        data: the signed bytes.
        signature: the signature file's bytes.
        allowed_signers: the file.

    Returns:
        ``(ok, who or why not)``: the principal whose key signed it, or ssh-keygen's message.

    Raises:
        AttestationError: no such ``allowed_signers`` file, or no ssh-keygen.
    """
    allowed = Path(allowed_signers).expanduser()
    if not allowed.is_file():
        raise AttestationError(f"--allowed_signers={allowed}: no such file (lines of 'principal key-type base64-key').")
    exe = _ssh_keygen()
    with tempfile.TemporaryDirectory(prefix="hub-envs-verify-") as tmp:
        sig = Path(tmp) / "attestation.json.sig"
        sig.write_bytes(signature)
        found = subprocess.run(
            [exe, "-Y", "find-principals", "-s", str(sig), "-f", str(allowed)], capture_output=True, text=True, timeout=60
        )
        principals = [p for p in found.stdout.split() if p]
        if found.returncode != 0 or not principals:
            return False, "signed by a key that is not in the allowed signers" if found.returncode else "no principal"
        for principal in principals:
            out = subprocess.run(
                [exe, "-Y", "verify", "-f", str(allowed), "-I", principal, "-n", SIGNATURE_NAMESPACE, "-s", str(sig)],
                input=data,
                capture_output=True,
                timeout=60,
            )
            if out.returncode == 0:
                return True, principal
        return False, (out.stderr or out.stdout).decode("utf-8", "replace").strip() or "signature does not match"


# --- reading them back --------------------------------------------------------------------------


@dataclass(frozen=True)
class AttestationEntry:
    """One attestation file as found on the Hub: where (``merged`` on main, or an open pull request), and either
    the parsed attestation or why it could not be read.

    ``author`` is who the Hub says opened the pull request the file came from (its discussion data: for an open
    one, that pull request; for a merged file, the latest merged pull request whose merge left the file as it is on
    main), never the attestation's own ``attested_by``, which whoever wrote the file chose. None: no pull request
    brought it (someone with write access committed it directly) or the Hub did not say.
    """

    path: str
    where: str  # "merged" or "PR #N (open, by <author>)"
    revision: str  # the commit it was read at
    attestation: Attestation | None
    error: str | None
    data: bytes
    signature: bytes | None
    pr_num: int | None = None  # the open pull request it is in (None: merged on main)
    author: str | None = None
    merged_from: int | None = None  # the pull request a merged file came from

    @property
    def merged(self) -> bool:
        return self.pr_num is None

    @property
    def signed(self) -> bool:
        return self.signature is not None

    def by(self) -> str:
        """Who attests, as far as the Hub knows (safe to print): ``bob`` (an open pull request's author), ``bob (merged
        PR #3)``, or why nobody is named."""
        if self.author is None:
            return "no pull request (committed directly by the repo's owner)" if self.merged else "unknown"
        return f"{safe_text(self.author)} (merged PR #{self.merged_from})" if self.merged else safe_text(self.author)


def _read(repo_id: str, path: str, revision: str, token: str | None) -> bytes | None:
    try:
        with hub_io.translate_hub_errors(repo_id, revision):
            local = hf_hub_download(repo_id, path, revision=revision, repo_type=hub_io.REPO_TYPE, token=token)
    except HostileResponseError:
        raise  # the endpoint lies: not a file that went missing
    except HubError:
        return None
    return Path(local).read_bytes()


def _entries_at(
    repo_id: str, revision: str, where: str, pr_num: int | None, token: str | None, skip=None
) -> list[AttestationEntry]:
    files = hub_io.list_remote_files(repo_id, revision, token=token)
    out = []
    for path in sorted(files):
        if not (is_attestation_file(path) and path.endswith(".json")):
            continue
        data = _read(repo_id, path, revision, token)
        if data is None or (skip is not None and skip.get(path) == data):
            continue  # unchanged from main: listed once, as merged
        sig = _read(repo_id, path + SIGNATURE_SUFFIX, revision, token) if path + SIGNATURE_SUFFIX in files else None
        where_text = f"{repo_id}@{revision[:12]}:{path}" if pr_num is None else f"{repo_id} refs/pr/{pr_num}:{path}"
        try:
            att, error = Attestation.from_json(data, where=where_text), None
            if att.repo_id.lower() != repo_id.lower():
                att, error = None, f"{where_text}: attests {att.repo_id}, not {repo_id}"
        except AttestationError as e:
            att, error = None, str(e)
        out.append(AttestationEntry(path, where, revision, att, error, data, sig, pr_num))
    return out


_DIFF_PATH = re.compile(r"^diff --git a/(\S+) b/(\S+)$", re.MULTILINE)


def _merged_authors(repo_id: str, head: str, paths: list[str], token: str | None) -> dict[str, tuple[str, int]]:
    """``{path: (author, pull request number)}`` for the files of ``head`` a merged pull request brought as they are:
    the latest merged pull request whose diff touches the path and whose merge commit holds the same blob as ``head``
    (the Hub's discussion data and its paths-info; a later direct edit names nobody)."""
    wanted = set(paths)
    if not wanted:
        return {}
    client = hub_io.api(token)
    found: dict[str, tuple[str, int]] = {}
    try:
        _find_merged_authors(client, repo_id, head, wanted, found)
    except HostileResponseError:
        raise
    except HubError as e:  # e.g. discussions disabled on this repo: then no pull request brought any file
        logger.debug("%s: the Hub's pull requests could not be read (%s); merged attestations name no author", repo_id, e)
    return found


def _find_merged_authors(client: Any, repo_id: str, head: str, wanted: set[str], found: dict[str, tuple[str, int]]) -> None:
    with hub_io.translate_hub_errors(repo_id, head):
        now = {f.path: getattr(f, "blob_id", None) for f in client.get_paths_info(repo_id, sorted(wanted), revision=head)}
        merged = [
            d
            for d in client.get_repo_discussions(repo_id, repo_type=hub_io.REPO_TYPE, discussion_type="pull_request")
            if d.status == "merged"
        ]
        for d in sorted(merged, key=lambda d: d.num, reverse=True):
            if not wanted:
                break
            details = client.get_discussion_details(repo_id, d.num, repo_type=hub_io.REPO_TYPE)
            touched = {p for m in _DIFF_PATH.finditer(details.diff or "") for p in m.groups()} & wanted
            if not touched or not details.merge_commit_oid:
                continue
            then = client.get_paths_info(repo_id, sorted(touched), revision=details.merge_commit_oid)
            for f in then:
                if f.path in touched and now.get(f.path) is not None and getattr(f, "blob_id", None) == now[f.path]:
                    found[f.path] = (str(d.author), d.num)
            wanted -= touched  # a newer merge that changed the file hides older ones, whoever matches


def merged_attestations(repo_id: str, revision: str | None = None, *, token: str | None = None) -> list[AttestationEntry]:
    """The attestations merged by the repo's owner, each with the author of the pull request it came from
    (:attr:`AttestationEntry.author`).

    Args:
        repo_id: the env repo.
        revision: where to read them (None: main).
        token: the Hub token.

    Returns:
        The entries (an invalid file is an entry with ``error`` set); none when the repo does not exist.

    Raises:
        ConfigError: ``repo_id`` is no repo id.
    """
    check_repo_id(repo_id)
    head = revision or hub_io.remote_head(repo_id, token=token)
    if head is None:
        return []
    entries = _entries_at(repo_id, head, "merged", None, token)
    authors = _merged_authors(repo_id, head, [e.path for e in entries], token)
    return [
        dataclasses.replace(e, author=authors[e.path][0], merged_from=authors[e.path][1]) if e.path in authors else e
        for e in entries
    ]


def collect_attestations(repo_id: str, *, token: str | None = None) -> list[AttestationEntry]:
    """Every attestation of a repo: merged (on main) and in open pull requests (files they add or change).

    Args:
        repo_id: the env repo.
        token: the Hub token.

    Returns:
        The entries, merged first, then by pull request.

    Raises:
        ConfigError: ``repo_id`` is no repo id.
        HubError: the Hub cannot be read.
    """
    check_repo_id(repo_id)
    merged = merged_attestations(repo_id, token=token)
    on_main = {e.path: e.data for e in merged}
    out = list(merged)
    client = hub_io.api(token)
    with hub_io.translate_hub_errors(repo_id, "main"):
        prs = [
            d
            for d in client.get_repo_discussions(repo_id, repo_type=hub_io.REPO_TYPE, discussion_status="open")
            if d.is_pull_request
        ]
    for d in sorted(prs, key=lambda d: d.num):
        with hub_io.translate_hub_errors(repo_id, f"refs/pr/{d.num}"):
            head = client.repo_info(repo_id, revision=f"refs/pr/{d.num}", repo_type=hub_io.REPO_TYPE).sha
        found = _entries_at(repo_id, head, f"PR #{d.num} (open, by {safe_text(d.author)})", d.num, token, skip=on_main)
        out += [dataclasses.replace(e, author=str(d.author)) for e in found]
    return out


def _signature_mark(entry: AttestationEntry, verified: tuple[bool, str] | None) -> str:
    """``unsigned``, ``signed`` (not checked), ``verified`` or ``SIGNATURE FAILED``."""
    if not entry.signed:
        return "unsigned"
    if verified is None:
        return "signed"
    return "verified" if verified[0] else "SIGNATURE FAILED"


def matrix_text(entries: list[AttestationEntry], verified: dict[int, tuple[bool, str]] | None = None) -> str:
    """The matrix env revision x stack -> verdict (each cell says whether the claim is signed), the stacks' legend, and one
    line per file naming who attests: the pull request's author, as the Hub says. Every repo-controlled field is made
    safe to print (:func:`hub_envs._text.safe_text`).

    Args:
        entries: :func:`collect_attestations`' entries.
        verified: ``{entry index: (ok, who)}`` of the signatures checked.

    Returns:
        The text ``hub-envs attestations`` prints.
    """
    good = [(i, e) for i, e in enumerate(entries) if e.attestation is not None]
    if not entries:
        return "No attestations yet: hub-envs reproduce --repo_id=<repo>@<sha> --trust_remote_code=true --attest=true"
    verified = verified or {}
    lines = []
    if good:
        revisions = list(dict.fromkeys(e.attestation.sha for _, e in good))  # type: ignore[union-attr]
        stacks = list(dict.fromkeys(e.attestation.stack_digest for _, e in good))  # type: ignore[union-attr]
        cells: dict[tuple[str, str], list[str]] = {}
        for i, e in good:
            a = e.attestation
            done, of = a.tasks_reproduced  # type: ignore[union-attr]
            mark = f"{'✓' if a.reproduced else '✗'}{f' {done}/{of} tasks' if of else ''} {_signature_mark(e, verified.get(i))}"  # type: ignore[union-attr]
            mark += "" if e.merged else f" (PR #{e.pr_num})"
            cells.setdefault((a.sha, a.stack_digest), []).append(mark)  # type: ignore[union-attr]
        header = ["env revision \\ stack", *stacks]
        rows = [[sha[:12], *[", ".join(cells.get((sha, st), ["–"])) for st in stacks]] for sha in revisions]
        widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
        lines.append("  ".join(h.ljust(w) for h, w in zip(header, widths)))
        lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
        lines += [
            "",
            "✓ reproduced, ✗ did not. unsigned: only the pull request's author (below) vouches for it; signed: an OpenSSH",
            "signature is attached (check it: --verify=true --allowed_signers=FILE); verified: a key in your allowed_signers",
            "signed these bytes. (PR #N): in an open pull request, not merged yet. N/M tasks: of a benchmark suite's M tasks,",
            "N reproduced (each task's verdict under files).",
            "",
            "stacks:",
        ]
        for st in stacks:
            a = next(e.attestation for _, e in good if e.attestation.stack_digest == st)  # type: ignore[union-attr]
            lines.append(f"  {st}  {safe_text(describe_stack(a.stack))}")  # type: ignore[union-attr]
    lines += ["", "files:"]
    for i, e in enumerate(entries):
        path = safe_text(e.path)
        where = "merged" if e.merged else e.where
        if e.attestation is None:
            lines.append(f"  {path} [{where}]: INVALID: {safe_text(e.error)}")
            continue
        a = e.attestation
        sig = _signature_mark(e, None)
        if i in verified:
            ok, who = verified[i]
            sig = f"{'signature verified' if ok else 'SIGNATURE FAILED'} ({safe_text(who)})"
        line = f"  {path} [{where}]: {a.verdict} at {a.sha[:12]}, by {e.by()}, {safe_text(a.created_at)}; {sig}"
        if a.attested_by and a.attested_by != e.author:
            line += f"; the file names its author '{safe_text(a.attested_by)}' (self-declared, not checked)"
        lines.append(line)
        if a.tasks:
            done, of = a.tasks_reproduced
            per = ", ".join(f"{safe_text(t['task'])} {'✓' if t['reproduced'] else '✗'}" for t in a.tasks)
            lines.append(f"    {done} of {of} tasks reproduced: {per}")
    return "\n".join(lines)
