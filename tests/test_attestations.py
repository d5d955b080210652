"""Reproduction attestations: ``hub-envs reproduce --attest=true`` opens a pull request on the env repo whose file
validates; ``hub-envs attestations`` lists it (open, then merged); the owner merges and a re-push renders the
"Reproduced on" table in the card; an OpenSSH-signed attestation verifies and a tampered one fails; a non-owner
cannot merge. Against the loopback Hub, through the unmodified huggingface_hub client, with a second account."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import Hub, _start_hub
from helpers import TINY, copy_env
from huggingface_hub import CommitOperationAdd, CommitOperationDelete, HfApi, hf_hub_download
from huggingface_hub.errors import HfHubHTTPError

from hub_envs import diff, errors, load_env, push_env, reproduce
from hub_envs.cli import main as cli_main
from hub_envs.operations.attest import attest
from hub_envs.repo.attestations import Attestation, collect_attestations, stack_digest
from hub_envs.testing import hub_environment

BOB_TOKEN = "hf_bob_attest_token"
REPO = "alice/att-tiny"


@pytest.fixture(scope="module")
def hub_two_users(tmp_path_factory) -> Iterator[Hub]:
    """The server's own account (``local``, the default ``HF_TOKEN``) manages every repo; ``bob`` is a third party.
    (A server with more accounts needs a token for its own: an anonymous caller would act as the owner.)"""
    yield from _start_hub(
        tmp_path_factory.mktemp("hub-att"),
        token="hf_owner_attest_token",
        suffix="-att",
        env={"HUB_ENVS_SERVER_USERS": f"bob:{BOB_TOKEN}"},
    )


@pytest.fixture(scope="module")
def pushed(hub_two_users):
    return push_env(TINY, REPO, episodes=2, progress=False)


@pytest.fixture(scope="module")
def bob_report(hub_two_users, pushed, tmp_path_factory):
    """A reproduction bob ran (the report a third party would attest)."""
    out = tmp_path_factory.mktemp("bob-report")
    return reproduce(f"{REPO}@{pushed.sha}", trust_remote_code=True, workers=1, out=out, progress=False, token=BOB_TOKEN)


def _pr_file(api: HfApi, num: int, suffix: str = ".json") -> tuple[str, bytes]:
    files = [f for f in api.list_repo_files(REPO, revision=f"refs/pr/{num}") if f.startswith("reproductions/")]
    (path,) = [f for f in files if f.endswith(suffix)]
    local = hf_hub_download(REPO, path, revision=f"refs/pr/{num}", endpoint=api.endpoint, force_download=True)
    return path, Path(local).read_bytes()


def test_reproduce_attest_opens_a_pull_request_listed_then_merged_into_the_card(hub_two_users, pushed, tmp_path, capsys):
    api = hub_two_users.api
    out = tmp_path / "out"
    code = cli_main(
        ["reproduce", f"--repo_id={REPO}", f"--revision={pushed.sha}", "--trust_remote_code=true", "--workers=1",
         f"--out={out}", "--attest=true"]
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "pull request #1" in printed
    # main did not move: the attestation waits in refs/pr/1 for the owner
    assert api.repo_info(REPO).sha == pushed.sha
    (pr,) = [d for d in api.get_repo_discussions(REPO) if d.num == 1]
    assert pr.is_pull_request and pr.status == "open" and pr.author == "local"
    path, data = _pr_file(api, 1)
    att = Attestation.from_json(data)  # validates
    assert path == att.path == f"reproductions/{att.created_at[:10]}-{pushed.sha[:12]}-{att.stack_digest}.json"
    assert (att.repo_id, att.sha, att.verdict, att.reproduced) == (REPO, pushed.sha, "REPRODUCED", True)
    assert att.content_digest == pushed.manifest.content_digest
    assert att.dataset_fingerprint == pushed.manifest.dataset["fingerprint"]
    assert att.report_sha256 == hashlib.sha256((out / "report.json").read_bytes()).hexdigest()
    assert att.replay["ok"] and att.replay["episodes"] == 2 and att.replay["diverged"] == 0
    (bench,) = att.benchmarks
    assert bench["passed"] and all(m["ci_low"] <= m["reproduced"] <= m["ci_high"] for m in bench["metrics"])
    assert {"lerobot", "torch", "numpy", "gymnasium", "hub-envs"} <= set(att.stack["packages"])
    assert att.stack["cpu"] and att.stack["python"] and "numpy" in att.stack["requirement_closure"]
    assert att.stack_digest == stack_digest(att.stack)
    assert att.command[:2] == ("hub-envs", "reproduce") and f"--revision={pushed.sha}" in att.command
    assert "--trust_remote_code=true" in att.command and not any("attest" in c for c in att.command)

    # listed while open
    assert cli_main(["attestations", f"--repo_id={REPO}"]) == 0
    listing = capsys.readouterr().out
    assert f"{pushed.sha[:12]}" in listing and "✓ unsigned (PR #1)" in listing and att.stack_digest in listing
    (file_line,) = [line for line in listing.splitlines() if line.strip().startswith(path)]
    assert file_line.endswith("; unsigned") and "by local," in file_line

    # merged by the owner; a re-push of the same content renders the card table and keeps the file
    api.merge_pull_request(REPO, 1)
    assert cli_main(["attestations", f"--repo_id={REPO}"]) == 0
    listing = capsys.readouterr().out
    assert "[merged]" in listing and "(PR #1)" not in listing and "by local (merged PR #1)" in listing
    again = push_env(TINY, REPO, episodes=2, progress=False)
    assert again.created_commit and again.manifest.content_digest == pushed.manifest.content_digest
    card = Path(hf_hub_download(REPO, "README.md", revision=again.sha, endpoint=hub_two_users.endpoint)).read_text()
    assert "## Reproduced on" in card
    (row,) = [line for line in card.splitlines() if f"`{pushed.sha[:12]}`" in line and line.startswith("|")]
    assert "✓ reproduced" in row and att.stack_digest in row and att.stack["packages"]["lerobot"] in row
    assert path in api.list_repo_files(REPO, revision=again.sha)
    # only the card (and the manifest's hash of it) was committed again: nothing rebuilt...
    assert "build" not in again.timings
    old, new = ({f.path: f.blob_id for f in api.list_repo_tree(REPO, revision=r, recursive=True) if hasattr(f, "blob_id")}
                for r in (pushed.sha, again.sha))  # fmt: skip
    changed = {p for p in new if old.get(p) != new[p]}
    assert changed == {"README.md", "hub_env.json", path}, changed
    # ...and it is exactly what a full rebuild makes: a forced push finds nothing to commit
    forced = push_env(TINY, REPO, episodes=2, progress=False, force=True)
    assert not forced.created_commit and forced.sha == again.sha and "build" in forced.timings
    # nothing new since: the next push makes no commit
    assert not push_env(TINY, REPO, episodes=2, progress=False).created_commit


def test_a_third_party_signs_and_verifies_and_a_tampered_one_fails_and_cannot_merge(
    hub_two_users, pushed, bob_report, tmp_path, capsys
):
    if shutil.which("ssh-keygen") is None:  # pragma: no cover - openssh-client is a dev requirement
        pytest.skip("ssh-keygen is not installed (apt-get install openssh-client)")
    key = tmp_path / "bob_ed25519"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", "bob", "-f", str(key)], check=True)
    allowed = tmp_path / "allowed_signers"
    allowed.write_text("bob@example.org " + " ".join(key.with_suffix(".pub").read_text().split()[:2]) + "\n")

    result = attest(bob_report, command=["hub-envs", "reproduce", f"--repo_id={REPO}"], sign_key=key, token=BOB_TOKEN)
    api, bob = hub_two_users.api, HfApi(endpoint=hub_two_users.endpoint, token=BOB_TOKEN)
    assert result.signed and result.attestation.attested_by == "bob"
    num = result.pr_num
    assert [d.author for d in api.get_repo_discussions(REPO) if d.num == num] == ["bob"]
    _, sig = _pr_file(api, num, ".json.sig")
    assert sig.startswith(b"-----BEGIN SSH SIGNATURE-----")

    assert cli_main(["attestations", f"--repo_id={REPO}", "--verify=true", f"--allowed_signers={allowed}"]) == 0
    assert "signature verified (bob@example.org)" in capsys.readouterr().out
    # a key that is not in allowed_signers does not verify
    other = tmp_path / "other_allowed"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(tmp_path / "k2")], check=True)
    other.write_text("eve " + " ".join((tmp_path / "k2.pub").read_text().split()[:2]) + "\n")
    assert cli_main(["attestations", f"--repo_id={REPO}", "--verify=true", f"--allowed_signers={other}"]) == 1
    assert "SIGNATURE FAILED" in capsys.readouterr().out

    # a non-owner cannot merge it (nor push to main)
    with pytest.raises(HfHubHTTPError) as err:
        bob.merge_pull_request(REPO, num)
    assert err.value.response.status_code == 403
    # tampered: the file changed in the pull request after signing (still a valid attestation, not the signed bytes)
    path, data = _pr_file(api, num)
    doctored = json.loads(data)
    doctored["attested_by"] = "alice"
    bob.create_commit(
        REPO,
        [CommitOperationAdd(path_in_repo=path, path_or_fileobj=(json.dumps(doctored, indent=2, sort_keys=True) + "\n").encode())],
        commit_message="tweak",
        revision=f"refs/pr/{num}",
    )
    assert cli_main(["attestations", f"--repo_id={REPO}", "--verify=true", f"--allowed_signers={allowed}"]) == 1
    captured = capsys.readouterr()
    assert "SIGNATURE FAILED" in captured.out and "failed verification" in captured.err
    entries = collect_attestations(REPO)
    assert any(e.pr_num == num and e.attestation.attested_by == "alice" for e in entries)


def test_invalid_attestations_are_refused_with_the_field_named(bob_report, tmp_path):
    att = Attestation.from_report(bob_report, requirements=(), command=["hub-envs", "reproduce"])
    d = att.to_dict()
    with pytest.raises(errors.AttestationError, match="'sha'"):
        Attestation.from_dict({**d, "sha": "not-a-sha"})
    with pytest.raises(errors.AttestationError, match="contradicts"):
        Attestation.from_dict({**d, "verdict": "NOT REPRODUCED"})
    with pytest.raises(errors.AttestationError, match="stack_digest"):
        Attestation.from_dict({**d, "stack": {**d["stack"], "cpu": "something else"}})
    with pytest.raises(errors.AttestationError, match="format_version"):
        Attestation.from_dict({**d, "format_version": 99})
    assert Attestation.from_json(att.to_json()) == att
    # --sign_key without --attest, or a missing key: refused before anything runs
    assert cli_main(["reproduce", f"--repo_id={REPO}", f"--sign_key={tmp_path / 'k'}"]) == 1
    assert cli_main(["reproduce", f"--repo_id={REPO}", "--attest=true", f"--sign_key={tmp_path / 'nope'}"]) == 1


def test_a_merged_attestation_leaves_main_and_every_later_commit_loadable(hub_two_users, tmp_path):
    """Issue 29 item 1: once the owner merges an attestation, the merge commit, the card-only re-push and a later code
    change all load, reproduce and diff in a fresh HF_HOME; the content tag follows the card that shows the
    reproduction; the re-pushes keep the merged files; a later commit is attested in a file of its own."""
    repo, api = "alice/att-later", hub_two_users.api

    def fresh(name: str):  # another machine: an empty HF_HOME (and hub-envs home) pointed at the same Hub
        return hub_environment(hub_two_users.endpoint, tmp_path / name)

    def bob_attests(sha: str, name: str):
        with fresh(name):
            report = reproduce(f"{repo}@{sha}", trust_remote_code=True, workers=1, out=tmp_path / name, progress=False)
            assert report.reproduced, report.summary()
            return attest(report, command=["hub-envs", "reproduce", f"--repo_id={repo}@{sha}"], token=BOB_TOKEN)

    first = push_env(TINY, repo, episodes=2, progress=False)
    one = bob_attests(first.sha, "bob-1")
    api.merge_pull_request(repo, one.pr_num)
    merged = api.repo_info(repo).sha
    assert merged != first.sha and one.path in api.list_repo_files(repo, revision=merged)
    with fresh("merge-commit"):
        loaded = load_env(f"{repo}@{merged}", trust_remote_code=True)
        assert loaded.revision == merged
        loaded.unregister()

    # the card-only re-push: the content tag moves onto it, so the card's own pinned line loads the card with the table
    card_commit = push_env(TINY, repo, episodes=2, progress=False)
    assert card_commit.created_commit and "build" not in card_commit.timings
    assert {t.name: t.target_commit for t in api.list_repo_refs(repo).tags} == {first.content_tag: card_commit.sha}
    assert one.path in api.list_repo_files(repo, revision=card_commit.sha)  # kept, not deleted
    with fresh("card-line"):
        loaded = load_env(f"{repo}@{first.content_tag}", trust_remote_code=True)  # what the card's "Load it" pins
        assert loaded.revision == card_commit.sha
        loaded.unregister()
        card = Path(hf_hub_download(repo, "README.md", revision=first.content_tag)).read_text()
        assert "## Reproduced on" in card and f"`{first.sha[:12]}`" in card

    # a later code change keeps the merged files and loads, diffs and reproduces; bob attests it in a new file
    changed = copy_env(tmp_path, edits={"tiny.py": lambda text: text + "\n# a comment: new content, same behaviour\n"})
    later = push_env(changed, repo, episodes=2, progress=False)
    assert later.manifest.content_digest != first.manifest.content_digest
    assert one.path in api.list_repo_files(repo, revision=later.sha)
    with fresh("diff"):
        assert diff(
            f"{repo}@{merged}", f"{repo}@{later.sha}", trust_remote_code=True, write=False, random_episodes=0
        ).behaviour_identical
    two = bob_attests(later.sha, "bob-2")
    assert two.path != one.path
    in_pr = api.list_repo_files(repo, revision=f"refs/pr/{two.pr_num}")
    assert one.path in in_pr and two.path in in_pr
    api.merge_pull_request(repo, two.pr_num)
    with fresh("after-second-merge"):
        load_env(repo, trust_remote_code=True).unregister()  # main, with both attestations


def test_files_beyond_the_manifest_are_still_refused_unless_they_are_attestations(hub_two_users, tmp_path):
    """The one rule (repo_format.beyond_manifest) accepts reproductions/<name>.json and .json.sig only: code or any other
    file a merged pull request adds is still refused by a load."""
    from hub_envs.repo.format import beyond_manifest  # new: imported here so the module still imports on older main

    repo, api = "alice/att-strict", hub_two_users.api
    push_env(TINY, repo, episodes=2, progress=False)
    bob = HfApi(endpoint=hub_two_users.endpoint, token=BOB_TOKEN)
    for i, name in enumerate(("reproductions/helper.py", "reproductions/notes.txt", "reproductions/a/b.json", "notes.json")):
        assert not beyond_manifest(name)
        pr = bob.create_commit(
            repo, [CommitOperationAdd(path_in_repo=name, path_or_fileobj=b"{}\n")], commit_message="add", create_pr=True
        )
        api.merge_pull_request(repo, pr.pr_num)
        sha = api.repo_info(repo).sha
        with hub_environment(hub_two_users.endpoint, tmp_path / f"h{i}"), pytest.raises(errors.IntegrityError, match=name):
            load_env(f"{repo}@{sha}", trust_remote_code=True)
        api.create_commit(repo, [CommitOperationDelete(path_in_repo=name)], commit_message="remove")
