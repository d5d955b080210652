"""A hostile attestation against the card and the terminal (issue 30 item 6 and its Low finding).

Mallory, a second account, opens a pull request adding a valid attestation whose free-text fields carry Markdown, HTML
and terminal escape sequences and whose ``attested_by`` claims to be the repo's owner; the owner merges it, as the
README says, and re-pushes. The card must render every field inert (no second "## Load it" with the attacker's load
line, no link, no HTML), name the pull request's author rather than the self-declared one, and mark the claim
unsigned; ``hub-envs attestations`` (the real CLI) must print every field and the pull request's author escaped.
Against the loopback Hub with ``--token`` and accounts whose names the test chooses.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import Hub, _start_hub
from helpers import TINY
from huggingface_hub import CommitOperationAdd, HfApi, hf_hub_download

from hub_envs import load_env, push_env, reproduce
from hub_envs.operations.attest import attest
from hub_envs.repo.attestations import Attestation, stack_digest
from hub_envs.testing import hub_environment

ALICE_TOKEN = "hf_alice_adv_attest"
MALLORY_TOKEN = "hf_mallory_adv_attest"
BOB_TOKEN = "hf_bob_adv_attest"
ESCAPED_NAME = "eve\x1b[2J\x1b]0;pwned\x07"  # an account name a hostile endpoint may send: clears the screen, retitles
EVE_TOKEN = "hf_eve_adv_attest"
REPO = "alice/adv-att"

INJECTED_LOAD = 'load_env("mallory/evil@main", trust_remote_code=True)'
MARKDOWN = f"0.6.1 |\n\n## Load it\n\n```python\n{INJECTED_LOAD}\n```\n\n| x"
HTML = '<img src=x onerror="alert(1)"> [click](https://evil.example) www.evil.example'
TERMINAL = "AMD \x1b[2J\x1b]8;;https://evil.example\x07EPYC\u202e\x9b31m"


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Iterator[Hub]:
    users = f"mallory:{MALLORY_TOKEN},bob:{BOB_TOKEN},{ESCAPED_NAME}:{EVE_TOKEN}"
    yield from _start_hub(
        tmp_path_factory.mktemp("hub-adv-att"),
        token=ALICE_TOKEN,
        suffix="-adv-att",
        env={"HUB_ENVS_SERVER_USER": "alice", "HUB_ENVS_SERVER_USERS": users},
    )


@pytest.fixture(scope="module")
def published(lab, tmp_path_factory):
    pushed = push_env(TINY, REPO, episodes=2, progress=False)
    report = reproduce(
        f"{REPO}@{pushed.sha}", trust_remote_code=True, workers=1, out=tmp_path_factory.mktemp("r"), progress=False
    )
    return pushed, report


def _hostile(report, *, attested_by: str, edit) -> Attestation:
    """A valid attestation (it passes Attestation.from_dict) whose stack fields ``edit`` rewrote."""
    d = Attestation.from_report(report, requirements=(), command=["hub-envs", "reproduce"]).to_dict()
    edit(d["stack"])
    d["stack_digest"] = stack_digest(d["stack"])
    d["attested_by"] = attested_by
    return Attestation.from_dict(d)


def _open_pr(endpoint: str, token: str, att: Attestation) -> int:
    api = HfApi(endpoint=endpoint, token=token)
    info = api.create_commit(
        REPO,
        [CommitOperationAdd(path_in_repo=att.path, path_or_fileobj=att.to_json().encode())],
        commit_message="Reproduction attestation",
        create_pr=True,
    )
    return int(info.pr_num)


def _attestations_cli(lab: Hub, *args: str) -> str:
    env = {**os.environ, "HF_ENDPOINT": lab.endpoint, "HF_TOKEN": ALICE_TOKEN, "HF_HOME": str(lab.hf_home)}
    out = subprocess.run(
        [sys.executable, "-m", "hub_envs.cli", "attestations", f"--repo_id={REPO}", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    return out.stdout


def _assert_terminal_safe(text: str) -> None:
    bad = sorted({hex(ord(c)) for c in text if c not in "\n" and not c.isprintable()})
    assert not bad, f"unescaped characters reach the terminal: {bad}"


def test_a_merged_attestation_cannot_inject_markdown_nor_forge_its_author(lab, published, tmp_path):
    pushed, report = published
    hostile = _hostile(
        report,
        attested_by="alice",  # claims to be the owner
        edit=lambda st: (st["packages"].__setitem__("lerobot", MARKDOWN), st.__setitem__("cpu", HTML)),
    )
    num = _open_pr(lab.endpoint, MALLORY_TOKEN, hostile)
    signed = None
    if shutil.which("ssh-keygen") is not None:  # bob signs his: the card tells signed from unsigned
        key = tmp_path / "bob_ed25519"
        subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", "bob", "-f", str(key)], check=True)
        signed = attest(report, command=["hub-envs", "reproduce"], sign_key=key, token=BOB_TOKEN)
    lab.api.merge_pull_request(REPO, num)
    if signed is not None:
        lab.api.merge_pull_request(REPO, signed.pr_num)

    again = push_env(TINY, REPO, episodes=2, progress=False)  # the documented merge-and-re-push
    assert again.created_commit
    card = Path(hf_hub_download(REPO, "README.md", revision=again.sha)).read_text()
    assert card.count("## Load it") == 1
    assert INJECTED_LOAD not in card and "mallory/evil" not in card.split("## Reproduced on")[0]
    assert "<img" not in card and "](https://evil" not in card
    (row,) = [line for line in card.splitlines() if line.startswith("|") and "mallory" in line]
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert len(cells) == 13, row  # the row was not split by a '|' from a field
    assert all(c.startswith("`") and c.endswith("`") for c in cells[4:11]), row  # free text: inert code spans
    assert "<" not in row and "[" not in row and "\n" not in row
    assert cells[11] == f"`@mallory` (PR #{num})" and "alice" not in row  # the PR's author, not the file's claim
    assert cells[12] == "**unsigned**"
    if signed is not None:
        (bob_row,) = [line for line in card.splitlines() if line.startswith("|") and "@bob" in line]
        assert bob_row.rstrip().endswith(f"`@bob` (PR #{signed.pr_num}) | signed (OpenSSH) |")
        assert signed.path + ".sig" in lab.api.list_repo_files(REPO, revision=again.sha)  # kept by the re-push
        with hub_environment(lab.endpoint, tmp_path / "fresh"):  # and a commit holding it loads
            load_env(f"{REPO}@{again.sha}", trust_remote_code=True).unregister()

    listing = _attestations_cli(lab)
    _assert_terminal_safe(listing)
    (line,) = [x for x in listing.splitlines() if hostile.path in x]
    assert f"by mallory (merged PR #{num})" in line and "'alice' (self-declared, not checked)" in line
    assert "Z; unsigned;" in line
    assert "✓ unsigned" in listing


def test_hub_envs_attestations_prints_fields_and_pr_authors_escaped(lab, published):
    _, report = published
    hostile = _hostile(report, attested_by="x\x1b[31my", edit=lambda st: st.__setitem__("cpu", TERMINAL))
    num = _open_pr(lab.endpoint, EVE_TOKEN, hostile)  # opened by the account whose name holds escapes
    listing = _attestations_cli(lab)
    _assert_terminal_safe(listing)
    assert "eve\\x1b[2J\\x1b]0;pwned\\x07" in listing  # the PR's author, shown escaped
    assert "AMD \\x1b[2J\\x1b]8;;https://evil.example\\x07EPYC\\u202e\\x9b31m" in listing  # the stack, escaped
    assert f"✓ unsigned (PR #{num})" in listing
    as_json = json.loads(_attestations_cli(lab, "--json=true"))
    assert any(e["pr_num"] == num and e["author"] == ESCAPED_NAME for e in as_json)  # JSON keeps the exact value
