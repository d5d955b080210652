"""Pull requests on the loopback Hub server, driven by the unmodified ``huggingface_hub`` client (0.35 and 1.x):
``create_commit(create_pr=True)``, reads at ``refs/pr/N``, ``get_repo_discussions``, ``get_discussion_details``,
``merge_pull_request``, ``change_discussion_status``, and who may do what (the Hub's rules: anyone opens, the
owner merges)."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
from conftest import Hub, _start_hub
from huggingface_hub import CommitOperationAdd, CommitOperationDelete, HfApi, hf_hub_download
from huggingface_hub.errors import HfHubHTTPError

OWNER_TOKEN = "hf_owner_test_token"  # the server's own account (``local``): with more accounts, a token is required
BOB_TOKEN = "hf_bob_test_token"  # a second account: owns the namespace "bob" only


@pytest.fixture(scope="module")
def two_users(tmp_path_factory) -> Iterator[Hub]:
    """A server whose own account (``local``, the default client's ``HF_TOKEN``) manages every repo, and a
    second account ``bob``."""
    yield from _start_hub(
        tmp_path_factory.mktemp("hub-prs"), token=OWNER_TOKEN, suffix="-prs", env={"HUB_ENVS_SERVER_USERS": f"bob:{BOB_TOKEN}"}
    )


def _add(path: str, data: bytes) -> CommitOperationAdd:
    return CommitOperationAdd(path_in_repo=path, path_or_fileobj=data)


def _bob(hub: Hub) -> HfApi:
    return HfApi(endpoint=hub.endpoint, token=BOB_TOKEN)


def test_a_pull_request_is_opened_read_listed_and_merged(two_users):
    owner, bob, repo = two_users.api, _bob(two_users), "alice/prs-merge"
    owner.create_repo(repo)
    main0 = owner.create_commit(repo, [_add("a.txt", b"a0"), _add("b.txt", b"b0")], commit_message="start").oid
    assert bob.whoami()["name"] == "bob"

    info = bob.create_commit(
        repo, [_add("reproductions/x.json", b"{}"), CommitOperationDelete("b.txt")], commit_message="Attest", create_pr=True
    )
    assert info.pr_num == 1 and info.pr_revision == "refs/pr/1"
    assert info.pr_url == f"{two_users.endpoint}/alice/prs-merge/discussions/1"
    # main did not move; the PR's files are read at refs/pr/1 (sent url-encoded: refs%2Fpr%2F1)
    assert owner.repo_info(repo).sha == main0
    assert "reproductions/x.json" not in owner.list_repo_files(repo)
    assert sorted(owner.list_repo_files(repo, revision="refs/pr/1")) == [".gitattributes", "a.txt", "reproductions/x.json"]
    assert owner.repo_info(repo, revision="refs/pr/1").sha == info.oid
    path = hf_hub_download(repo, "reproductions/x.json", revision="refs/pr/1", endpoint=two_users.endpoint)
    assert json.loads(open(path).read()) == {}
    refs = owner.list_repo_refs(repo, include_pull_requests=True)
    assert [(r.ref, r.target_commit) for r in refs.pull_requests] == [("refs/pr/1", info.oid)]

    # a second commit to the open PR moves refs/pr/1 only
    more = bob.create_commit(repo, [_add("c.txt", b"c")], commit_message="more", revision="refs/pr/1")
    assert owner.repo_info(repo, revision="refs/pr/1").sha == more.oid and owner.repo_info(repo).sha == main0

    (listed,) = list(owner.get_repo_discussions(repo))
    assert (listed.num, listed.title, listed.status, listed.is_pull_request, listed.author) == (1, "Attest", "open", True, "bob")
    details = owner.get_discussion_details(repo, 1)
    assert details.target_branch == "refs/heads/main" and details.merge_commit_oid is None
    assert [e.type for e in details.events] == ["comment", "commit", "commit"]

    # main moved meanwhile on another file: the merge keeps both sides
    owner.create_commit(repo, [_add("a.txt", b"a1")], commit_message="owner edit")
    owner.merge_pull_request(repo, 1)
    merged = owner.get_discussion_details(repo, 1)
    assert merged.status == "merged" and merged.merge_commit_oid == owner.repo_info(repo).sha
    assert sorted(owner.list_repo_files(repo)) == [".gitattributes", "a.txt", "c.txt", "reproductions/x.json"]
    a = hf_hub_download(repo, "a.txt", endpoint=two_users.endpoint, force_download=True)
    assert open(a, "rb").read() == b"a1"
    assert [d.status for d in owner.get_repo_discussions(repo, discussion_status="closed")] == ["merged"]
    assert list(owner.get_repo_discussions(repo, discussion_status="open")) == []


def test_only_the_owner_merges_or_writes_and_anyone_opens(two_users):
    owner, bob, repo = two_users.api, _bob(two_users), "alice/prs-perms"
    owner.create_repo(repo)
    head = owner.create_commit(repo, [_add("a.txt", b"a")], commit_message="start").oid
    with pytest.raises(HfHubHTTPError) as err:  # a direct commit to someone else's main
        bob.create_commit(repo, [_add("x.txt", b"x")], commit_message="push")
    assert err.value.response.status_code == 403
    pr = bob.create_commit(repo, [_add("x.txt", b"x")], commit_message="proposal", create_pr=True)
    with pytest.raises(HfHubHTTPError) as err:
        bob.merge_pull_request(repo, pr.pr_num)
    assert err.value.response.status_code == 403 and "only its owner" in str(err.value)
    assert owner.repo_info(repo).sha == head and owner.get_discussion_details(repo, pr.pr_num).status == "open"
    for attempt in (lambda: bob.delete_repo(repo), lambda: bob.create_repo("alice/not-bobs")):
        with pytest.raises(HfHubHTTPError) as err:
            attempt()
        assert err.value.response.status_code == 403
    assert owner.repo_info(repo).sha == head
    # bob owns his namespace: there he commits and merges
    bob.create_repo("bob/own")
    bob.create_commit("bob/own", [_add("a.txt", b"a")], commit_message="start")
    mine = bob.create_commit("bob/own", [_add("b.txt", b"b")], commit_message="pr", create_pr=True)
    bob.merge_pull_request("bob/own", mine.pr_num)
    assert "b.txt" in bob.list_repo_files("bob/own")


def test_a_pull_request_is_closed_reopened_and_conflicts_are_refused(two_users):
    owner, bob, repo = two_users.api, _bob(two_users), "alice/prs-close"
    owner.create_repo(repo)
    owner.create_commit(repo, [_add("a.txt", b"a")], commit_message="start")
    pr = bob.create_commit(repo, [_add("a.txt", b"bob's")], commit_message="edit a", create_pr=True)
    event = bob.change_discussion_status(repo, pr.pr_num, "closed", comment="never mind")  # its author may
    assert event.new_status == "closed"
    assert [d.status for d in owner.get_repo_discussions(repo)] == ["closed"]
    with pytest.raises(HfHubHTTPError):  # a closed PR cannot be merged
        owner.merge_pull_request(repo, pr.pr_num)
    owner.change_discussion_status(repo, pr.pr_num, "open")
    owner.create_commit(repo, [_add("a.txt", b"owner's")], commit_message="owner edit")  # the same file, otherwise
    with pytest.raises(HfHubHTTPError) as err:
        owner.merge_pull_request(repo, pr.pr_num)
    assert err.value.response.status_code == 409 and "a.txt" in str(err.value)
    assert owner.get_discussion_details(repo, pr.pr_num).status == "open"
    # numbering goes on; a missing PR is a 404
    second = bob.create_commit(repo, [_add("b.txt", b"b")], commit_message="add b", create_pr=True)
    assert second.pr_num == 2 and [d.num for d in owner.get_repo_discussions(repo)] == [2, 1]
    with pytest.raises(HfHubHTTPError) as err:
        owner.get_discussion_details(repo, 9)
    assert err.value.response.status_code == 404


def test_pull_requests_survive_a_restart(tmp_path):
    hub_iter = _start_hub(tmp_path, token=None, suffix="-restart")
    hub = next(hub_iter)
    try:
        api = hub.api
        api.create_repo("alice/prs-restart")
        api.create_commit("alice/prs-restart", [_add("a.txt", b"a")], commit_message="start")
        pr = api.create_commit("alice/prs-restart", [_add("b.txt", b"b")], commit_message="add b", create_pr=True)
        hub.server.restart()
        assert api.repo_info("alice/prs-restart", revision="refs/pr/1").sha == pr.oid
        api.merge_pull_request("alice/prs-restart", 1)
        assert api.get_discussion_details("alice/prs-restart", 1).status == "merged"
    finally:
        hub_iter.close()
