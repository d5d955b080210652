"""The author's journey (issue 29): push -> card -> another account attests -> the owner merges -> re-push -> the card's
pinned line loads in a fresh HF_HOME -> reproduce -> attest again.

Real parts throughout: a ``hub-envs serve --token`` subprocess with two accounts (alice, the server's own account, and
bob), the unmodified huggingface_hub client, alice's ``push_env`` (the Python API the README shows), bob's
``hub-envs reproduce --attest=true`` and ``hub-envs attestations`` as subprocesses of the installed CLI, each user
in an HF_HOME of their own, and the very lines the card prints (its pinned ``load_env`` line, its ``hub-envs
reproduce`` line) taken from the card and run as written. The env is tests/fixtures/tiny_env with 2 episodes, so the
story takes seconds.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers import TINY
from huggingface_hub import HfApi, hf_hub_download

from hub_envs import load_env, push_env
from hub_envs.testing import HubServer, hub_environment

ALICE_TOKEN = "hf_journey_alice"
BOB_TOKEN = "hf_journey_bob"
REPO = "alice/tiny-journey"


@pytest.fixture
def lab(tmp_path) -> Iterator[HubServer]:
    server = HubServer(
        tmp_path / "hub-data",
        token=ALICE_TOKEN,
        env={"HUB_ENVS_SERVER_USER": "alice", "HUB_ENVS_SERVER_USERS": f"bob:{BOB_TOKEN}"},
    )
    try:
        yield server
    finally:
        server.kill()
        server.remove_log()


def _hub_envs(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``hub-envs ...`` as a user types it, in the environment of the ``hub_environment`` block it runs in."""
    script = Path(sys.executable).with_name("hub-envs")
    cmd = [str(script)] if script.is_file() else [sys.executable, "-m", "hub_envs.cli"]
    return subprocess.run([*cmd, *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def _card(revision: str) -> str:
    return Path(hf_hub_download(REPO, "README.md", revision=revision)).read_text(encoding="utf-8")


def _card_lines(card: str) -> tuple[str, list[str]]:
    """The card's pinned load line (under "## Load it") and its ``hub-envs reproduce`` arguments."""
    load = card.split("## Load it", 1)[1].split("\n## ", 1)[0]
    (line,) = re.findall(r"^loaded = (load_env\(\"[^\"]+\", trust_remote_code=True\))$", load, re.MULTILINE)
    (repro,) = re.findall(r"^hub-envs (reproduce .+)$", card, re.MULTILINE)
    return line, repro.split()


def test_author_pushes_bob_attests_alice_merges_and_the_cards_line_keeps_working(lab, tmp_path):
    # 1. alice publishes; the card pins the content tag and shows no reproduction yet
    with hub_environment(lab.endpoint, tmp_path / "alice", token=ALICE_TOKEN):
        first = push_env(TINY, REPO, episodes=2, progress=False)
        card = _card(first.sha)
    load_line, repro_args = _card_lines(card)
    assert f'"{REPO}@{first.content_tag}"' in load_line and "## Reproduced on" not in card

    # 2. bob reproduces what the card says and attests it: a pull request, main unchanged
    with hub_environment(lab.endpoint, tmp_path / "bob", token=BOB_TOKEN):
        out = _hub_envs(*repro_args, "--attest=true", "--workers=1", f"--out={tmp_path / 'bob-out'}", cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "REPRODUCED" in out.stdout and "pull request #1" in out.stdout
    assert f"merge_pull_request('{REPO}', 1)" in out.stdout

    # 3. alice merges it, as the command said, and re-pushes: only the card changes, and the content tag follows it
    alice = HfApi(endpoint=lab.endpoint, token=ALICE_TOKEN)
    assert alice.repo_info(REPO).sha == first.sha
    alice.merge_pull_request(REPO, 1)
    with hub_environment(lab.endpoint, tmp_path / "alice", token=ALICE_TOKEN):
        again = push_env(TINY, REPO, episodes=2, progress=False)
    assert again.created_commit and again.content_tag == first.content_tag
    assert alice.repo_info(REPO).sha == again.sha
    assert [f for f in alice.list_repo_files(REPO, revision=again.sha) if f.startswith("reproductions/")]

    # 4. someone with a fresh HF_HOME (no token) runs the card's pinned line: it loads the commit whose card shows bob
    with hub_environment(lab.endpoint, tmp_path / "carol", token=None):
        card = _card("main")
        assert _card_lines(card) == (load_line, repro_args)  # the same pinned lines...
        loaded = eval(load_line, {"load_env": load_env})  # ...run as written
        try:
            assert loaded.revision == again.sha  # the commit with the table, not the first one
        finally:
            loaded.unregister()
        card = _card(loaded.revision)
        (row,) = [r for r in card.split("## Reproduced on", 1)[1].splitlines() if r.startswith("| `")]
        assert "✓ reproduced" in row and "`@bob` (PR #1)" in row and "**unsigned**" in row

    # 5. bob, on another machine, reproduces the card's line again and attests this commit: a new file, PR #2
    with hub_environment(lab.endpoint, tmp_path / "bob-laptop", token=BOB_TOKEN):
        out = _hub_envs(*repro_args, "--attest=true", "--workers=1", f"--out={tmp_path / 'bob-out-2'}", cwd=tmp_path)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "REPRODUCED" in out.stdout and "pull request #2" in out.stdout
        listing = _hub_envs("attestations", f"--repo_id={REPO}", cwd=tmp_path)
    assert listing.returncode == 0, listing.stderr
    assert "by bob (merged PR #1)" in listing.stdout and "[PR #2 (open, by bob)]" in listing.stdout
    assert first.sha[:12] in listing.stdout and again.sha[:12] in listing.stdout  # one file per attested commit
    files = alice.list_repo_files(REPO, revision="refs/pr/2")
    assert len([f for f in files if f.startswith("reproductions/") and f.endswith(".json")]) == 2
