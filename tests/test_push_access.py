"""push_env (and ``reproduce --attest``) ask the Hub who the caller is before anything is built (issue 29 item 5): no
token, a refused token, a read-only token, or an account that cannot write the namespace is said at once, naming
HF_TOKEN / ``hf auth login``; nothing of the env runs and nothing is published. Against the loopback Hub with
``--token`` and a second account, through the unmodified huggingface_hub client and the real CLI; the Hub's own
whoami shapes (a read-only token, organizations) through a rewriting proxy in front of it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import Hub, _start_hub
from helpers import copy_env
from lying_endpoint import LyingEndpoint

from hub_envs import errors, push_env
from hub_envs.testing import hub_environment

ALICE_TOKEN = "hf_alice_access_token"
BOB_TOKEN = "hf_bob_access_token"


@pytest.fixture(scope="module")
def lab_hub(tmp_path_factory) -> Iterator[Hub]:
    """A server with ``--token`` (alice's: the server's own account) and a second account, bob."""
    yield from _start_hub(
        tmp_path_factory.mktemp("hub-access"),
        token=ALICE_TOKEN,
        suffix="-access",
        env={"HUB_ENVS_SERVER_USER": "alice", "HUB_ENVS_SERVER_USERS": f"bob:{BOB_TOKEN}"},
    )


@pytest.fixture
def marked_env(tmp_path, monkeypatch) -> tuple[Path, Path]:
    """A copy of tiny_env whose code, once imported, writes a marker file: "nothing of the env ran" is checked."""
    marker = tmp_path / "env-code-ran"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(marker))
    folder = copy_env(
        tmp_path,
        edits={
            "tiny.py": lambda t: t + "\nimport os as _os, pathlib as _pl\n_pl.Path(_os.environ['HUB_ENVS_TEST_MARKER']).touch()\n"
        },
    )
    return folder, marker


def _cli(args: list[str], *, endpoint: str, home: Path, token: str | None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "HF_TOKEN"}
    env.update(HF_ENDPOINT=endpoint, HF_HOME=str(home), HUB_ENVS_HOME=str(home / "hub-envs"), HF_HUB_DISABLE_TELEMETRY="1")
    if token is not None:
        env["HF_TOKEN"] = token
    return subprocess.run([sys.executable, "-m", "hub_envs.cli", *args], capture_output=True, text=True, env=env, timeout=300)


def test_push_without_a_token_says_so_before_anything_runs(lab_hub, marked_env, tmp_path):
    folder, marker = marked_env
    out = _cli(["push", f"--env_dir={folder}", "--repo_id=alice/access-none", "--episodes=2"],
               endpoint=lab_hub.endpoint, home=tmp_path / "home", token=None)  # fmt: skip
    assert out.returncode == 1, out.stderr
    assert "no token is set" in out.stderr and "HF_TOKEN" in out.stderr and "hf auth login" in out.stderr, out.stderr
    assert "refused the token" not in out.stderr and "nothing was built or published" in out.stderr
    assert not marker.exists()  # the env's code was never imported: no check, no dataset, no GIF
    assert "alice/access-none" not in [r.id for r in lab_hub.api.list_models()]


def test_a_refused_token_and_an_account_outside_the_namespace_are_said_early(lab_hub, marked_env, tmp_path):
    from hub_envs.repo.hub_io import check_write_access  # here, not above: the CLI tests also run against older hub-envs

    folder, marker = marked_env
    with hub_environment(lab_hub.endpoint, tmp_path / "wrong", token="hf_not_a_token"):
        with pytest.raises(errors.HubAccessError, match="refused the token") as refused:
            push_env(folder, "alice/access-wrong", episodes=2, progress=False)
    assert "HF_TOKEN" in str(refused.value)
    with hub_environment(lab_hub.endpoint, tmp_path / "bob", token=BOB_TOKEN):
        with pytest.raises(errors.HubAccessError, match="'bob'.*cannot write to the namespace 'alice'") as outside:
            push_env(folder, "alice/access-bob", episodes=2, progress=False)
    assert "bob/access-bob" in str(outside.value)  # what bob can do instead
    assert not marker.exists()
    assert not [r for r in lab_hub.api.list_models() if r.id.startswith("alice/access-")]
    # the same accounts where they may write: bob in his namespace, the server's own account (alice) anywhere it manages
    with hub_environment(lab_hub.endpoint, tmp_path / "bob", token=BOB_TOKEN):
        assert check_write_access("bob/access-bob") == "bob"
        assert check_write_access("alice/access-bob", pull_request=True) == "bob"  # anyone may open a pull request
    with hub_environment(lab_hub.endpoint, tmp_path / "alice", token=ALICE_TOKEN):
        assert check_write_access("lab/access-shared") == "alice"


def test_reproduce_attest_without_a_token_says_so_before_reproducing(lab_hub, marked_env, tmp_path):
    folder, marker = marked_env
    with hub_environment(lab_hub.endpoint, tmp_path / "alice", token=ALICE_TOKEN):
        sha = push_env(folder, "alice/access-attest", episodes=2, progress=False).sha
    marker.unlink()
    out = _cli(["reproduce", "--repo_id=alice/access-attest", f"--revision={sha}", "--trust_remote_code=true", "--attest=true",
                f"--out={tmp_path / 'out'}"], endpoint=lab_hub.endpoint, home=tmp_path / "anon", token=None)  # fmt: skip
    assert out.returncode == 1 and "no token is set" in out.stderr and "hf auth login" in out.stderr, out.stderr
    assert not marker.exists() and not (tmp_path / "out").exists()


def _whoami_as(answer: dict):
    """Answer whoami as huggingface.co would for some account (the rest is the real server's)."""

    def rewrite(method, path, status, headers, body):
        if path.startswith("/api/whoami-v2"):
            return 200, {**headers, "Content-Type": "application/json"}, json.dumps(answer).encode()
        return status, headers, body

    return rewrite


@pytest.mark.parametrize(
    ("role", "orgs", "repo_id", "refused"),
    [
        ("read", [], "carol/env", "read-only"),
        ("write", [{"name": "lab", "roleInOrg": "write"}], "lab/env", None),
        ("write", [{"name": "lab", "roleInOrg": "read"}], "lab/env", "cannot write to the namespace 'lab'"),
        ("write", [], "dave/env", "cannot write to the namespace 'dave'"),
        ("fineGrained", [], "dave/env", None),  # its scopes are the Hub's to judge, at publish time
    ],
)
def test_the_hubs_whoami_rules_decide_before_the_push(lab_hub, tmp_path, role, orgs, repo_id, refused):
    from hub_envs.repo.hub_io import check_write_access

    answer = {"type": "user", "name": "carol", "orgs": orgs, "auth": {"type": "access_token", "accessToken": {"role": role}}}
    with LyingEndpoint(lab_hub.endpoint, rewrite_answer=_whoami_as(answer)) as lie:
        with hub_environment(lie.endpoint, tmp_path / "home", token=ALICE_TOKEN):
            if refused is None:
                assert check_write_access(repo_id) == "carol"
            else:
                with pytest.raises(errors.HubAccessError, match=refused):
                    check_write_access(repo_id)
