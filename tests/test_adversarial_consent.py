"""No code runs without consent, and consent for one commit never runs another: against a hostile repo
AND a hostile endpoint (a rewriting proxy in front of the real loopback Hub, :mod:`lying_endpoint`).

Each test reproduces one attack of the red-team findings with the real client, server, cache and
loaders; the payload is env code that writes a marker file when imported, so "nothing ran" is a fact
the test can check.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from helpers import TINY, copy_env
from lying_endpoint import LyingEndpoint

from hub_envs import env_from_dataset, errors, load_env, push_env, trust
from hub_envs._compat import HF_HUB_MAJOR
from hub_envs.errors import UnpinnedRevisionWarning
from hub_envs.paths import hub_envs_home
from hub_envs.repo.refs import parse_repo_ref
from hub_envs.testing import hub_environment

PAYLOAD = "import os, pathlib\npathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('pwned')\n"


@pytest.fixture
def marker(tmp_path, monkeypatch) -> Path:
    path = tmp_path / "pwned-marker"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(path))
    return path


def _push(folder: Path, repo_id: str):
    return push_env(folder, repo_id, episodes=1, progress=False)


@pytest.fixture
def two_commits(hub, tmp_path, marker):
    """mallory/env: commit A (benign) and then commit B whose code writes the marker when imported."""
    a = _push(TINY, "mallory/env")
    b = _push(copy_env(tmp_path, name="evil", edits={"tiny.py": lambda s: PAYLOAD + s}), "mallory/env")
    marker.unlink(missing_ok=True)  # push_env imported B's code on the publisher's side
    return a.sha, b.sha


def _swap(a: str, b: str):
    """A proxy that serves commit ``b`` whenever ``a`` is asked for, and says it is ``a``."""

    def path(method: str, p: str) -> str:
        return p.replace(a, b)

    def answer(method, p, status, headers, body):
        headers = {k: (v.replace(b, a) if k.lower() == "x-repo-commit" else v) for k, v in headers.items()}
        if p.startswith("/api/"):
            body = body.replace(b.encode(), a.encode())
        return status, headers, body

    return path, answer


# --- 1. a dataset names its env: data, never a path ------------------------------------------


@pytest.mark.parametrize("named", ["./payload", "/ABS/payload", "~/payload", "mallory/env@main", "mallory/env\n"])
def test_a_dataset_naming_a_local_folder_never_runs_its_code(hub, tmp_path, marker, monkeypatch, named):
    sha = _push(TINY, "alice/tiny").sha
    snapshot = load_env(f"alice/tiny@{sha}", trust_remote_code=True, check=False)
    snapshot.unregister()
    payload = copy_env(tmp_path, name="payload", edits={"tiny.py": lambda s: PAYLOAD + s})
    marker.unlink(missing_ok=True)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path))
    dataset = shutil.copytree(snapshot.path / "dataset", tmp_path / "dataset-copy")
    meta = json.loads((dataset / "meta" / "hub_envs.json").read_text())
    meta["env_meta"]["env_repo_id"] = named.replace("/ABS", str(tmp_path))
    (dataset / "meta" / "hub_envs.json").write_text(json.dumps(meta))
    assert payload.is_dir()

    with pytest.raises(errors.ReproductionError, match="not a Hub repo id"):
        env_from_dataset(dataset)  # no consent given: nothing may run
    assert not marker.exists()


# --- 2. consent binds one commit and its content ------------------------------------------------


def test_a_pinned_commit_served_as_another_is_refused(hub, tmp_path, marker, two_commits):
    a, b = two_commits
    path, _ = _swap(a, b)
    with LyingEndpoint(hub.endpoint, rewrite_path=path) as lie, hub_environment(lie.endpoint, tmp_path / "victim"):
        with pytest.raises(errors.IntegrityError, match=f"served commit {b} instead"):
            load_env(f"mallory/env@{a}", trust_remote_code=True)
    assert not marker.exists()


def test_trust_in_a_commit_does_not_cover_other_content_served_under_its_id(hub, tmp_path, marker, two_commits):
    a, b = two_commits
    trust("mallory/env", a)  # reads A's manifest from the real Hub: consent is bound to A's content
    path, answer = _swap(a, b)
    with (
        LyingEndpoint(hub.endpoint, rewrite_path=path, rewrite_answer=answer) as lie,
        hub_environment(lie.endpoint, tmp_path / "victim"),
    ):
        os.environ["HUB_ENVS_HOME"] = str(hub_envs_home_of(hub))  # the trust list that holds A
        with pytest.raises(errors.UntrustedCodeError, match="for other content"):
            load_env(f"mallory/env@{a}")
    assert not marker.exists()


def hub_envs_home_of(hub) -> Path:
    return hub.hf_home.parent / f"{hub.hf_home.name}.hub-envs"


def test_trust_entries_of_an_older_hub_envs_are_not_honoured_silently(hub, tmp_path, marker, two_commits):
    _, b = two_commits
    legacy = hub.hf_home / "hub_envs" / "trusted.json"  # where hub-envs kept sha-only entries
    legacy.parent.mkdir(parents=True)
    legacy.write_text(json.dumps({"mallory/env": {b: "2026-01-01T00:00:00+00:00"}}))
    with pytest.raises(errors.UntrustedCodeError, match="by its sha alone"):
        load_env(f"mallory/env@{b}")
    assert not marker.exists()
    trust("mallory/env", b)  # the interactive re-confirmation records the content digest
    load_env(f"mallory/env@{b}", check=False).unregister()
    assert marker.exists()


# --- 3 and 10. a header the client would turn into a path ------------------------------------


def _relative(target: Path, start: Path) -> str:
    return os.path.relpath(target, start)


@pytest.mark.parametrize("header", ["ETag", "X-Linked-Etag", "X-Repo-Commit"])
def test_a_hostile_header_is_refused_before_the_client_writes_anything(hub, tmp_path, marker, two_commits, header):
    """The red-team's one-call consent bypass: a file whose ETag is a path to the trust list, whose body
    trusts the payload commit. Refused on every huggingface_hub version in the test matrix."""
    _, b = two_commits
    victim = tmp_path / "victim"
    blobs = victim / "hub" / "models--mallory--env" / "blobs"
    trust_file = victim.parent / f"{victim.name}.hub-envs" / "trusted.json"
    evil_list = json.dumps(
        {"format": 2, "entries": {"mallory/env": {b: {"content_digest": "0" * 64, "trusted_at": "x"}}}}
    ).encode()

    def answer(method, p, status, headers, body):
        if "/resolve/" in p and p.endswith("/tiny.py"):
            value = f'"{_relative(trust_file, blobs)}"' if header != "X-Repo-Commit" else "../../../../escaped-commit"
            headers = {**headers, header: value}
            body = evil_list if method == "GET" else body
        return status, headers, body

    with LyingEndpoint(hub.endpoint, rewrite_answer=answer) as lie, hub_environment(lie.endpoint, victim):
        with pytest.raises(errors.HostileResponseError, match=header):
            load_env(f"mallory/env@{b}")
    assert not trust_file.exists() and not marker.exists()
    assert not list(tmp_path.rglob("escaped-commit"))


def test_a_body_rewritten_under_its_honest_etag_is_refused_and_does_not_poison_the_cache(hub, tmp_path, marker, two_commits):
    """A proxy that changes a file's bytes (not its length) and keeps the Hub's ETag: the load refuses the commit (the manifest's
    sha256), nothing runs, and the blob stored under that ETag by huggingface_hub's fallback is not taken for
    the file later: a load through the honest endpoint fetches it again and succeeds (it failed for ever)."""
    a, _ = two_commits
    victim = tmp_path / "victim"

    def answer(method, p, status, headers, body):
        if method == "GET" and "/resolve/" in p and p.endswith("/tiny.py"):
            body = body[::-1]  # the same length, as the HEAD announced it
        return status, headers, body

    with LyingEndpoint(hub.endpoint, rewrite_answer=answer) as lie, hub_environment(lie.endpoint, victim):
        with pytest.raises(errors.IntegrityError, match="tiny.py"):
            load_env(f"mallory/env@{a}", trust_remote_code=True)
    assert not marker.exists()
    with hub_environment(hub.endpoint, victim):
        loaded = load_env(f"mallory/env@{a}", trust_remote_code=True)
        assert loaded.report.integrity.endswith("match the manifest")
        loaded.unregister()
    assert not marker.exists()


def test_hub_envs_state_lives_outside_the_hf_cache(hub):
    assert hub.hf_home not in hub_envs_home().parents and hub_envs_home() != hub.hf_home


# --- 5. the content tag ------------------------------------------------------------------------


def test_the_content_tag_pins_content(hub, tmp_path, marker, two_commits):
    a, b = two_commits
    tag = next(t.name for t in hub.api.list_repo_refs("mallory/env").tags if t.target_commit == a)
    with _no_unpinned_warning():
        load_env(f"mallory/env@{tag}", trust_remote_code=True, check=False).unregister()  # what the card pins
    hub.api.delete_tag("mallory/env", tag=tag)
    hub.api.create_tag("mallory/env", tag=tag, revision=b)  # moved onto other content
    marker.unlink(missing_ok=True)
    with pytest.raises(errors.IntegrityError, match=f"the tag {tag} names content"):
        load_env(f"mallory/env@{tag}", trust_remote_code=True)
    assert not marker.exists()


class _no_unpinned_warning:
    def __enter__(self):
        import warnings

        self._cm = warnings.catch_warnings(record=True)
        self._rec = self._cm.__enter__()
        warnings.simplefilter("always")

    def __exit__(self, *exc):
        self._cm.__exit__(*exc)
        assert not [w for w in self._rec if issubclass(w.category, UnpinnedRevisionWarning)]


# --- 6 and 10. a snapshot that failed is not left for anyone to run ----------------------------


def test_planted_env_py_bytecode_is_removed_with_the_snapshot_and_never_runs_on_lerobots_path(
    hub_storing_bytecode, tmp_path, marker
):
    import importlib.util
    import py_compile

    from helpers import republish

    sha = _push(TINY, "mallory/pyc").sha
    evil = tmp_path / "env.py"
    evil.write_text(PAYLOAD + "def make_env(*a, **k):\n    raise SystemExit('pwned')\n")

    def plant(folder: Path) -> None:
        cfile = Path(importlib.util.cache_from_source(str(folder / "env.py")))
        py_compile.compile(str(evil), cfile=str(cfile), invalidation_mode=py_compile.PycInvalidationMode.UNCHECKED_HASH)

    sha = republish(hub_storing_bytecode.api, "mallory/pyc", plant, fix_hashes=False)
    marker.unlink(missing_ok=True)
    with pytest.raises(errors.IntegrityError, match="unlisted"):
        load_env(f"mallory/pyc@{sha}", trust_remote_code=True)
    assert not (hub_storing_bytecode.hf_home / "hub" / "models--mallory--pyc" / "snapshots" / sha).exists()

    from lerobot.envs.factory import make_env

    envs = make_env(f"mallory/pyc@{sha}", n_envs=1, trust_remote_code=True)
    next(iter(next(iter(envs.values())).values())).close()
    assert not marker.exists()


def test_a_cached_snapshot_linking_outside_its_blobs_or_holding_extra_files_is_refused_then_healed(hub, tmp_path, marker):
    sha = _push(TINY, "alice/layout").sha
    load_env(f"alice/layout@{sha}", trust_remote_code=True, check=False).unregister()
    snap = hub.hf_home / "hub" / "models--alice--layout" / "snapshots" / sha
    outside = tmp_path / "outside-tiny.py"
    outside.write_bytes((snap / "tiny.py").read_bytes())  # the same bytes: sha256 alone would pass
    (snap / "tiny.py").unlink()
    (snap / "tiny.py").symlink_to(outside)
    (snap / "notes.txt").write_text("not from any download")
    with hub_environment(hub.endpoint, hub.hf_home, offline=True):
        with pytest.raises(errors.IntegrityError) as e:
            load_env(f"alice/layout@{sha}", trust_remote_code=True, check=False)
    assert "a link outside the cache's blobs/" in str(e.value) and "notes.txt (not in the manifest)" in str(e.value)
    assert not snap.exists()  # removed: the next online load downloads the commit afresh
    load_env(f"alice/layout@{sha}", trust_remote_code=True, check=False).unregister()
    assert (snap / "tiny.py").resolve().parent.name == "blobs"


# --- 15. small ones --------------------------------------------------------------------------


def test_the_trust_function_is_importable_from_the_package():
    import hub_envs
    import hub_envs.repo.trust_list  # noqa: F401  (importing the module must not shadow the function)

    assert callable(hub_envs.trust) and hub_envs.trust is hub_envs.repo.trust_list.trust


@pytest.mark.parametrize("ref", ["user/name\n", "user/name\x1b[2J", "user/naïve", "./user/name", "/abs/name", "~/x/y"])
def test_repo_ids_are_repo_ids(ref):
    with pytest.raises(errors.ConfigError):
        parse_repo_ref(ref)


def test_a_local_folder_with_an_at_sign_in_its_name_loads(tmp_path, monkeypatch):
    import gymnasium as gym

    folder = copy_env(tmp_path, name="my@env")
    monkeypatch.chdir(tmp_path)
    loaded = load_env("./my@env")  # a path: your own code, no consent needed, and no raw gymnasium error
    try:
        assert loaded.is_local and "@" not in loaded.gym_id.split("/")[1]
        gym.make(loaded.gym_id).reset(seed=0)
    finally:
        loaded.unregister()
    assert folder.is_dir()


# --- issue 30 (1). a same-host redirect: the answer huggingface_hub takes a file's metadata from ---------------

#: what a hostile endpoint writes: a ``.pth`` file runs its import line at the next Python start
PTH = "import os, pathlib; pathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('pwned')\n"
REDIRECTS = {
    "relative": lambda endpoint, to: to,  # what huggingface_hub 0.35 and 1.x both follow for a HEAD
    "absolute": lambda endpoint, to: endpoint + to,  # followed by 1.x only (same host)
}


def _follows(redirect: str) -> bool:
    """Whether huggingface_hub's metadata HEAD follows this redirect (0.35: relative ones only)."""
    return redirect == "relative" or HF_HUB_MAJOR >= 1


def _redirecting(hub, name: str, site: Path, blobs: Path, redirect: str, to: str) -> LyingEndpoint:
    """A compromised endpoint: ``/resolve/`` of ``name`` answers a redirect (naming no commit) to ``to`` + the commit
    on its own host, whose answer names the commit asked for, a body that is a ``.pth`` line and an ETag that is the
    path from the cache's ``blobs/`` to ``site/evil.pth``. Everything else is the real Hub's."""
    etag = f'"{os.path.relpath(site / "evil.pth", blobs)}"'
    holder: list[LyingEndpoint] = []

    def serve(method: str, p: str):
        if "/resolve/" in p and p.endswith(f"/{name}"):
            sha = p.split("/resolve/")[1].split("/")[0]
            return 302, {"Location": REDIRECTS[redirect](holder[0].endpoint, f"{to}{sha}/{name}")}, b""
        if p.startswith(to):
            sha = p[len(to) :].split("/")[0]
            return 200, {"X-Repo-Commit": sha, "ETag": etag, "Content-Type": "text/plain"}, PTH.encode()
        return None

    holder.append(LyingEndpoint(hub.endpoint, serve=serve))
    return holder[0]


def _written_outside(tmp_path: Path, cache: Path) -> list[Path]:
    """Files under ``tmp_path`` outside the victim's ``cache`` (the server's store, the publisher's cache and env
    folder excepted)."""
    theirs = {"hub-data", "hf_home", "evil"}
    return [
        p
        for p in tmp_path.rglob("*")
        if p.is_file() and cache not in p.parents and not theirs & set(p.relative_to(tmp_path).parts)
    ]


@pytest.mark.parametrize("to", ["/hostile/", "/api/resolve-cache/models/mallory/env/"])
@pytest.mark.parametrize("redirect", sorted(REDIRECTS))
def test_a_same_host_redirect_cannot_make_load_env_write_outside_the_cache(hub, tmp_path, marker, two_commits, redirect, to):
    """Red-team finding (issue 30, High 1): the one-GET fetch hands the odd answer to hf_hub_download, whose HEAD
    follows the redirect and took the ETag of the final answer unchecked: a ``.pth`` landed in site-packages, without
    consent. Now the answer that carries the file's metadata is checked wherever it sits in the chain."""
    _, b = two_commits
    victim, site = tmp_path / "victim", tmp_path / "site-packages"
    site.mkdir()
    blobs = victim / "hub" / "models--mallory--env" / "blobs"
    with _redirecting(hub, "tiny.py", site, blobs, redirect, to) as lie, hub_environment(lie.endpoint, victim):
        with pytest.raises(errors.HubEnvsError) as raised:
            load_env(f"mallory/env@{b}")  # no consent
    assert not (site / "evil.pth").exists(), "the endpoint wrote a .pth outside the cache"
    assert _written_outside(tmp_path, victim / "hub") == [], "nothing but the cache is written"
    if _follows(redirect):  # else huggingface_hub took the redirect itself for the metadata: no commit, no file
        assert isinstance(raised.value, errors.HostileResponseError) and "ETag" in str(raised.value), raised.value
    assert not marker.exists()


@pytest.mark.parametrize("redirect", sorted(REDIRECTS))
def test_a_same_host_redirect_cannot_make_hub_envs_attestations_write_outside_the_cache(hub, tmp_path, marker, capsys, redirect):
    """``hub-envs attestations`` asks no consent: it reads the repo's attestation files with hf_hub_download. The
    hostile answer is refused with its type named, not skipped as a missing file."""
    from hub_envs.cli import main as cli_main

    sha = _push(TINY, "mallory/att").sha
    name = "2026-01-01-0123456789ab.json"
    hub.api.upload_file(path_or_fileobj=b"{}", path_in_repo=f"reproductions/{name}", repo_id="mallory/att")
    victim, site = tmp_path / "victim", tmp_path / "site-packages"
    site.mkdir()
    blobs = victim / "hub" / "models--mallory--att" / "blobs"
    with _redirecting(hub, name, site, blobs, redirect, "/hostile/") as lie, hub_environment(lie.endpoint, victim):
        code = cli_main(["attestations", "--repo_id=mallory/att"])
    assert not (site / "evil.pth").exists(), "the endpoint wrote a .pth outside the cache"
    assert _written_outside(tmp_path, victim / "hub") == []
    err = capsys.readouterr().err
    if _follows(redirect):
        assert code == 1 and "HostileResponseError" in err and "ETag" in err, err
    assert sha


@pytest.mark.parametrize("redirect", sorted(REDIRECTS))
def test_a_redirected_repo_info_cannot_name_a_commit_that_is_a_path(hub, tmp_path, redirect):
    """The repo-info answer is checked by its URL; a redirect to another path of the same host handed the client a
    body nobody checked, whose ``sha`` names cache paths: on 1.x snapshot_download wrote the tree listing to
    ``trees/<sha>.json``, outside the cache. ``env_from_dataset("user/dataset")`` downloads a dataset repo so."""
    hub.api.create_repo("mallory/data", repo_type="dataset")
    hub.api.upload_file(path_or_fileobj=b"{}", path_in_repo="meta/info.json", repo_id="mallory/data", repo_type="dataset")
    victim, site = tmp_path / "victim", tmp_path / "site-packages"
    site.mkdir()
    repo_folder = victim / "hub" / "datasets--mallory--data"
    escaped = os.path.relpath(site / "evil", repo_folder / "trees")
    holder: list[LyingEndpoint] = []

    def serve(method: str, p: str):
        if p.startswith("/api/datasets/mallory/data/revision/"):
            return 302, {"Location": REDIRECTS[redirect](holder[0].endpoint, "/hostile/info")}, b""
        if p.startswith("/hostile/info"):
            info = {"id": "mallory/data", "sha": escaped, "siblings": [{"rfilename": "meta/info.json"}]}
            return 200, {"Content-Type": "application/json"}, json.dumps(info).encode()
        if p.startswith("/api/datasets/mallory/data/tree/"):  # the listing of that "commit" (1.x asks for it)
            tree = [{"type": "file", "path": "meta/info.json", "oid": "0" * 40, "size": 2}]
            return 200, {"Content-Type": "application/json"}, json.dumps(tree).encode()
        return None

    holder.append(LyingEndpoint(hub.endpoint, serve=serve))
    with holder[0] as lie, hub_environment(lie.endpoint, victim):
        with pytest.raises(errors.HubEnvsError) as raised:
            env_from_dataset("mallory/data")
    assert list(site.iterdir()) == [], "the endpoint wrote outside the cache"
    assert isinstance(raised.value, errors.HostileResponseError) and "redirect" in str(raised.value), raised.value


def _entry(path: str, **extra) -> dict:
    return {"type": "file", "path": path, "oid": "0" * 40, "size": 2, **extra}


#: what a hostile tree listing says, and the value the refusal names
LISTINGS = {
    "a path out of the repo": ([_entry("reproductions/../../../../evil.json")], "escapes the repo"),
    "an LFS oid that is a path": (
        [_entry("reproductions/x.json", lfs={"oid": "../../../evil", "size": 2, "pointerSize": 130})],
        "LFS oid",
    ),
    "a next page elsewhere": ("next", "next page"),
}


@pytest.mark.parametrize("listing", sorted(LISTINGS))
def test_a_tree_listing_is_checked_on_every_page(hub, tmp_path, capsys, listing):
    """The tree API's entries name cache paths (``path``; on 1.x with Xet, ``lfs.oid`` names the blob): they are
    checked like the repo-info answer's, and a next page (``Link``) elsewhere than the tree API is refused, since its
    body would not be. ``hub-envs attestations`` lists a repo's files so."""
    from hub_envs.cli import main as cli_main

    hub.api.create_repo("mallory/tree")
    hub.api.upload_file(path_or_fileobj=b"{}", path_in_repo="reproductions/x.json", repo_id="mallory/tree")
    entries, says = LISTINGS[listing]
    holder: list[LyingEndpoint] = []

    def serve(method: str, p: str):
        if p.startswith("/api/models/mallory/tree/tree/"):
            if entries != "next":
                return 200, {"Content-Type": "application/json"}, json.dumps(entries).encode()
            link = f'<{holder[0].endpoint}/hostile/page2>; rel="next"'
            return 200, {"Content-Type": "application/json", "Link": link}, json.dumps([_entry("reproductions/x.json")]).encode()
        if p.startswith("/hostile/page2"):
            return 200, {"Content-Type": "application/json"}, json.dumps([_entry("../../../../evil.json")]).encode()
        return None

    holder.append(LyingEndpoint(hub.endpoint, serve=serve))
    with holder[0] as lie, hub_environment(lie.endpoint, tmp_path / "victim"):
        code = cli_main(["attestations", "--repo_id=mallory/tree"])
    err = capsys.readouterr().err
    assert code == 1 and "HostileResponseError" in err and says in err, err
    assert _written_outside(tmp_path, tmp_path / "victim" / "hub") == []


def test_the_env_py_lerobot_runs_fetches_the_rest_of_its_commit_through_the_endpoint_check(hub, tmp_path, marker, two_commits):
    """LeRobot's own loader (``make_env("user/name@sha", trust_remote_code=True)``, in a process that never imported
    hub-envs) runs the repo's ``env.py``, which downloads the rest of its commit: with hub-envs installed that
    download goes through the same check, so the redirect above writes nothing outside the cache there either."""
    import subprocess
    import sys

    a, _ = two_commits
    victim, site = tmp_path / "victim", tmp_path / "site-packages"
    site.mkdir()
    blobs = victim / "hub" / "models--mallory--env" / "blobs"
    code = f"from lerobot.envs.factory import make_env\nmake_env('mallory/env@{a}', n_envs=1, trust_remote_code=True)\n"
    with _redirecting(hub, "tiny.py", site, blobs, "relative", "/hostile/") as lie, hub_environment(lie.endpoint, victim):
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ), timeout=300)
    assert not (site / "evil.pth").exists(), "the endpoint wrote a .pth outside the cache"
    assert _written_outside(tmp_path, victim / "hub") == []
    assert run.returncode != 0 and "HostileResponseError" in run.stderr, run.stderr[-3000:]
    assert not marker.exists()
