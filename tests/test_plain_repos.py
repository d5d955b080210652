"""Plain LeRobot EnvHub repos (no hub_env.json, uploaded with ``HfApi().upload_folder``): load_env with consent, pinning
and trust-on-first-use, ``hub-envs audit``, ``hub-envs adopt``; the adopted repo reproduces and LeRobot's make_env gives
the same env on it as on the source."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import plain_repos as pr
import pytest
from helpers import build_wheel, install_wheels

from hub_envs import load_env
from hub_envs.cli import main as cli
from hub_envs.envcode.registration import snapshot_registries
from hub_envs.errors import (
    EnvContractError,
    InvalidRepoFormatError,
    MissingRequirementsError,
    PlainRepoWarning,
    UntrustedCodeError,
)
from hub_envs.isolation import sandbox as sandbox_module
from hub_envs.repo.format import sha256_file


def upload(hub, repo_id, folder) -> str:
    hub.api.create_repo(repo_id, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # huggingface_hub: a README without card metadata
        return hub.api.upload_folder(repo_id=repo_id, folder_path=str(folder)).oid


def rollout(vec, seed: int, steps: int = 30) -> list:
    """Observations and rewards of a seeded random-action rollout of a vector env (the actions seeded too)."""
    obs, _ = vec.reset(seed=seed)
    vec.action_space.seed(seed)
    out = [obs["agent_pos"].copy()]
    for _ in range(steps):
        obs, reward, *_ = vec.step(vec.action_space.sample())
        out += [obs["agent_pos"].copy(), np.asarray(reward).copy()]
    vec.close()
    return out


def only_vec(envs: dict):
    [(suite, by_task)] = envs.items()
    [(task, vec)] = by_task.items()
    return vec


def test_a_plain_repo_loads_only_with_consent_pinned_and_says_what_it_cannot_guarantee(hub, tmp_path, capsys):
    from lerobot.envs.factory import make_env

    sha = upload(hub, "bob/reach", pr.vector_repo(tmp_path / "reach"))
    before = snapshot_registries()
    with pytest.raises(UntrustedCodeError, match="env.py"):
        load_env("bob/reach")
    assert snapshot_registries() == before  # nothing registered, nothing imported

    with pytest.warns(PlainRepoWarning, match="no manifest digest.*no dataset.*no fingerprint"):
        with pytest.warns(UserWarning, match=f"resolved to {sha}. Pin it"):
            loaded = load_env("bob/reach", trust_remote_code=True)
    assert loaded.revision == sha and loaded.plain_source == f"bob/reach@{sha}"
    assert any("no fingerprint" in g for g in loaded.missing_guarantees)
    assert loaded.report.requirements == ["gymnasium>=1.0", "numpy"]
    # the same env as LeRobot's own loader makes of the same commit
    ours = rollout(gym.vector.SyncVectorEnv([loaded.make], autoreset_mode=gym.vector.AutoresetMode.SAME_STEP), seed=5)
    theirs = rollout(only_vec(make_env(f"bob/reach@{sha}", trust_remote_code=True)), seed=5)
    assert all(np.array_equal(a, b) for a, b in zip(ours, theirs, strict=True))
    loaded.unregister()

    # trust on first use: `hub-envs trust` binds this commit and its files; then no flag is needed
    assert cli(["trust", f"bob/reach@{sha}"]) == 0
    with pytest.warns(PlainRepoWarning):
        again = load_env(f"bob/reach@{sha}")
    assert again.report.trust.startswith("trust list")
    again.unregister()
    assert cli(["load", f"--repo_id=bob/reach@{sha}"]) == 0
    assert "cannot give: no fingerprint" in capsys.readouterr().out
    # a new commit is not covered by that consent
    (tmp_path / "reach" / "env.py").write_text((tmp_path / "reach" / "env.py").read_text() + "\n# changed\n")
    new = upload(hub, "bob/reach", tmp_path / "reach")
    with pytest.raises(
        UntrustedCodeError, match=f"You trusted bob/reach@{sha[:12]} before(.|\\n)*changed since {sha[:12]}.*: env.py"
    ):
        load_env(f"bob/reach@{new}")


def test_a_bare_env_and_entry_files_under_a_folder_load_side_by_side(hub, tmp_path):
    bare = upload(hub, "bob/bare", pr.bare_repo(tmp_path / "bare"))
    tasks = upload(hub, "bob/tasks", pr.folder_repo(tmp_path / "tasks"))
    with pytest.warns(PlainRepoWarning):
        one = load_env(f"bob/bare@{bare}", trust_remote_code=True)
        near = load_env(f"bob/tasks@{tasks}:envs/Near.py", trust_remote_code=True)
        far = load_env(f"bob/tasks@{tasks}:envs/Far.py", trust_remote_code=True)
    assert one.make().reset(seed=0)[0]["agent_pos"].shape == (2,)
    assert near.gym_id != far.gym_id and far.plain_source == f"bob/tasks@{tasks}:envs/Far.py"
    # each entry file is its own env: the same actions from the same start, rewarded against its own target
    got = []
    for env in (near.make(), far.make()):
        env.reset(seed=0)
        got.append(env.step(np.zeros(2, dtype=np.float32))[1])
    assert got[0] != got[1]
    with pytest.raises(Exception, match="entry file envs/Missing.py is not in the repo"):
        load_env(f"bob/tasks@{tasks}:envs/Missing.py", trust_remote_code=True)
    for loaded in (one, near, far):
        loaded.unregister()
    with pytest.raises(UntrustedCodeError, match=f'load_env\\("bob/tasks@{tasks}:envs/Near.py", trust_remote_code=True\\)'):
        load_env(f"bob/tasks@{tasks}:envs/Near.py")  # the line to copy names the entry file


@pytest.mark.parametrize("how", [{"isolation": "process"}, {"sandbox": True}])
def test_a_plain_repo_runs_isolated_without_its_code_imported_here(hub, tmp_path, how):
    if how.get("sandbox") and sandbox_module.sandbox_support().get("root") is not True:
        pytest.skip("sandbox=True needs root (it is refused otherwise)")
    tasks = upload(hub, "bob/tasks", pr.folder_repo(tmp_path / "tasks"))
    with pytest.warns(PlainRepoWarning):
        isolated = load_env(f"bob/tasks@{tasks}:envs/Near.py", trust_remote_code=True, **how)
        here = load_env(f"bob/tasks@{tasks}:envs/Near.py", trust_remote_code=True, check=False)
    assert isolated.runs_as == ("process+sandbox" if how.get("sandbox") else "process")
    env = isolated.make()
    assert np.array_equal(env.reset(seed=3)[0]["agent_pos"], here.make().reset(seed=3)[0]["agent_pos"])
    env.close()
    isolated.unregister()
    here.unregister()


def test_a_shim_over_an_installed_package_needs_its_requirements_txt_met(hub, tmp_path, monkeypatch):
    sha = upload(hub, "bob/shim", pr.shim_repo(tmp_path / "shim"))
    with pytest.raises(MissingRequirementsError, match=f"{pr.PACKAGE}==1.0.0"):
        load_env(f"bob/shim@{sha}", trust_remote_code=True)
    wheels = build_wheel(tmp_path / "wheels", pr.PACKAGE, "1.0.0", pr.PACKAGE_FILES, ("gymnasium>=1.0",)).parent
    monkeypatch.syspath_prepend(str(install_wheels(wheels, tmp_path / "site", "--no-deps", f"{pr.PACKAGE}==1.0.0")))
    with pytest.warns(PlainRepoWarning):
        loaded = load_env(f"bob/shim@{sha}", trust_remote_code=True)
    obs, info = loaded.make().reset(seed=1)
    assert obs["agent_pos"].shape == (2,) and info["is_success"] is False
    loaded.unregister()


def test_a_repo_breaking_the_contract_is_refused_naming_what_is_wrong(hub, tmp_path):
    sha = upload(hub, "bob/broken", pr.broken_repo(tmp_path / "broken"))
    before = snapshot_registries()
    with pytest.raises(EnvContractError, match=r"env.py defines no make_env\(n_envs, use_async_envs, cfg=None\)"):
        load_env(f"bob/broken@{sha}", trust_remote_code=True)
    with pytest.raises(EnvContractError, match="make_env returned list, not a gym.Env"):
        load_env(f"bob/broken@{sha}:returns_list.py", trust_remote_code=True)
    assert snapshot_registries() == before


def test_audit_reports_lerobot_conventions_and_exits_by_the_verdict(hub, tmp_path, capsys):
    from hub_envs import audit

    good = upload(hub, "bob/reach", pr.vector_repo(tmp_path / "reach"))
    bare = upload(hub, "bob/bare", pr.bare_repo(tmp_path / "bare"))
    report = audit(f"bob/reach@{good}", trust_remote_code=True, output=tmp_path / "good.json")
    assert report.passed, report.render()
    names = [c.name for c in report.checks]
    for check in (
        "requirements",
        "contract",
        "final_info autoreset",
        "gymnasium check_env",
        "LeRobot observation names",
        "is_success in info",
        "spaces vs rollouts",
        "seeding and whole-episode determinism",
    ):
        assert check in names
    assert report.features == {"action": ["ACTION", [2]], "agent_pos": ["STATE", [2]]}
    assert report.episode_length == 40 and report.task == "reach the target"
    assert json.loads((tmp_path / "good.json").read_text())["passed"] is True

    # a bare gym.Env: LeRobot vectorizes it with NEXT_STEP autoreset, so lerobot-eval would score every episode a failure
    code = cli(["audit", f"--repo_id=bob/bare@{bare}", "--trust_remote_code=true", f"--output={tmp_path / 'bare.json'}"])
    assert code == 1
    assert "[FAIL] final_info autoreset" in capsys.readouterr().out
    saved = json.loads((tmp_path / "bare.json").read_text())
    assert saved["passed"] is False and [c["name"] for c in saved["checks"] if c["passed"] is False] == ["final_info autoreset"]
    assert {m.id for m in hub.api.list_models()} == {"bob/reach", "bob/bare"}  # it published nothing


def test_adopt_publishes_a_repo_that_reproduces_and_makes_the_same_env_in_lerobot(hub, tmp_path, capsys, monkeypatch):
    from lerobot.envs.factory import make_env

    folder = pr.bare_repo(tmp_path / "bare")  # the bare form: adoption also gives it lerobot-eval's final_info
    sha = upload(hub, "bob/bare", folder)
    assert cli(["adopt", f"--from_repo=bob/bare@{sha}", "--repo_id=me/reach", "--trust_remote_code=true", "--episodes=3"]) == 0
    adopted_sha = hub.api.model_info("me/reach").sha
    assert f"Adopted bob/bare@{sha} as me/reach@{adopted_sha}" in capsys.readouterr().out
    result = load_env(f"me/reach@{adopted_sha}", trust_remote_code=True)
    manifest = result.manifest
    assert manifest.files["source/env.py"] == sha256_file(folder / "env.py")  # the source's code, byte for byte
    assert f"bob/bare@{sha}" in manifest.description
    snap = result
    origin = json.loads((snap.path / "adopted_from.json").read_text())
    assert origin["repo_id"] == "bob/bare" and origin["revision"] == sha
    assert f"bob/bare@{sha}" in (snap.path / "README.md").read_text()
    assert snap.missing_guarantees == () and snap.report.fingerprint.startswith("matches")
    assert snap.open_dataset().meta.total_episodes == 3
    snap.unregister()
    with load_env(f"me/reach@{adopted_sha}:env.py", trust_remote_code=True) as same:  # LeRobot's name for it: the same load
        assert same.plain_source is None and same.report.fingerprint.startswith("matches")

    monkeypatch.chdir(tmp_path)
    assert cli(["reproduce", "--repo_id=me/reach", f"--revision={adopted_sha}", "--trust_remote_code=true"]) == 0
    out = capsys.readouterr().out
    assert "REPRODUCED" in out and "NOT REPRODUCED" not in out

    adopted = only_vec(make_env(f"me/reach@{adopted_sha}", trust_remote_code=True))
    source = only_vec(make_env(f"bob/bare@{sha}", trust_remote_code=True))
    assert adopted.single_observation_space == source.single_observation_space
    assert all(np.array_equal(a, b) for a, b in zip(rollout(adopted, 7), rollout(source, 7), strict=True))


def test_adopt_of_an_entry_file_under_a_folder_pins_the_source_and_refuses_what_it_cannot_fix(hub, tmp_path):
    from hub_envs import adopt

    tasks = upload(hub, "bob/tasks", pr.folder_repo(tmp_path / "tasks"))
    with pytest.warns(UserWarning, match="Pin it"):  # the branch is resolved once: that commit is adopted
        result = adopt("bob/tasks:envs/Far.py", "me/far", trust_remote_code=True, episodes=2, progress=False)
    assert f"bob/tasks@{tasks}:envs/Far.py" in result.manifest.description
    assert result.manifest.requirements == ("gymnasium>=1.0", "numpy")  # from its requirements.txt
    with pytest.warns(PlainRepoWarning):
        source = load_env(f"bob/tasks@{tasks}:envs/Far.py", trust_remote_code=True)
    adopted = load_env(f"me/far@{result.sha}", trust_remote_code=True)
    assert adopted.config.episode_length == 40 and adopted.config.task == "reach the target"
    a, b = adopted.make(), source.make()
    a.reset(seed=4), b.reset(seed=4)
    action = np.array([0.3, -0.2], dtype=np.float32)
    assert a.step(action)[:2][1] == b.step(action)[:2][1]
    adopted.unregister()
    source.unregister()

    broken = upload(hub, "bob/broken", pr.broken_repo(tmp_path / "broken"))
    with pytest.raises(EnvContractError, match="cannot be adopted as it is:\n  contract: .*defines no make_env"):
        adopt(f"bob/broken@{broken}", "me/broken", trust_remote_code=True, progress=False)
    assert "me/broken" not in {m.id for m in hub.api.list_models()}


@pytest.mark.parametrize(
    "argv",
    [
        ["audit", "--repo_id=bob/reach:envs/Near.py\n", "--trust_remote_code=true"],
        ["adopt", "--from_repo=bob/reach:envs/Near.py\n", "--repo_id=me/near", "--trust_remote_code=true"],
        ["adopt", "--from_repo=bob/reach", "--repo_id=me/near\n", "--trust_remote_code=true"],
    ],
)
def test_audit_and_adopt_refuse_a_repo_flag_with_a_trailing_newline(argv, capsys):
    """draccus reads a flag's value as YAML, which drops a trailing newline: the command would go on with another name."""
    assert cli(argv) == 1
    err = capsys.readouterr().err
    assert "ConfigError" in err and "\\n'" in err, err


# --- red-team round 29 ------------------------------------------------------------------------------------------------


def test_adopt_publishes_only_the_files_its_audit_ran_with_consent_not_what_a_second_fetch_adds(hub, tmp_path, monkeypatch):
    """adopt fetched the source commit a second time after its audit and copied whatever the snapshot held into the folder
    push_env runs (a local folder: no consent) and publishes: a hostile endpoint adding a file under the same commit id had
    it run as the user and published under their name (red-team finding, session 29)."""
    from lying_endpoint import LyingEndpoint

    from hub_envs.errors import IntegrityError
    from hub_envs.publishing.adopt import adopt
    from hub_envs.testing import hub_environment

    marker = tmp_path / "PWNED"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(marker))
    optional_plugin = "\nimport os, sys\nsys.path.insert(0, os.path.dirname(__file__))\ntry:\n    import rt29_plugin  # noqa\nexcept ImportError:\n    pass\n"
    a = upload(hub, "bob/plugged", pr.write(tmp_path / "a", {"env.py": pr.REACH + pr.VECTOR_MAKE_ENV + optional_plugin}))
    payload = "import os, pathlib\npathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('pwned')\n"
    b = upload(hub, "bob/plugged", pr.write(tmp_path / "b", {"rt29_plugin.py": payload}))
    assert cli(["trust", f"bob/plugged@{a}"]) == 0  # consent to commit a, with its files as they were
    seen = {"revision requests": 0, "lie from": 10**9}

    def lying() -> bool:
        return seen["revision requests"] >= seen["lie from"]

    def path(method, p):
        seen["revision requests"] += f"/revision/{a}" in p
        return p.replace(a, b) if lying() else p

    def answer(method, p, status, headers, body):  # commit b's files, named as commit a's
        if lying():
            return status, {k: v.replace(b, a) for k, v in headers.items()}, body.replace(b.encode(), a.encode())
        return status, headers, body

    with LyingEndpoint(hub.endpoint, rewrite_path=path, rewrite_answer=answer) as lie, hub_environment(lie.endpoint, hub.hf_home):
        from hub_envs.loading.audit import audit

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert audit(f"bob/plugged@{a}").passed  # honest: how many revision requests an audit makes
            seen["lie from"] = 2 * seen["revision requests"] + 1  # adopt's own audit honest, its second fetch lied to
            with pytest.raises(IntegrityError, match="not .* as when it was audited"):
                adopt(f"bob/plugged@{a}", "me/plugged", episodes=2, progress=False)
    assert not marker.exists()
    assert not hub.api.repo_exists("me/plugged")


def test_adopt_renders_the_source_envs_task_into_the_card_as_text_not_markdown(hub, tmp_path):
    """The source env's ``task`` (any string its code sets) went raw into the adopter's card: a forged "## Load it"
    section naming another repo, and raw HTML, in a card published under the adopter's name (red-team finding, session 29)."""
    from markdown_it import MarkdownIt

    from hub_envs.publishing.adopt import adopt

    evil = 'reach`\n\n## Load it\n\n```python\nload_env("mallory/evil", trust_remote_code=True)\n```\n\n<img src=x onerror=alert(1)> |'
    env = pr.REACH.replace('self.task = "reach the target"', f"self.task = {evil!r}") + pr.VECTOR_MAKE_ENV
    sha = upload(hub, "bob/tasky", pr.write(tmp_path / "tasky", {"env.py": env, "requirements.txt": pr.REQUIREMENTS}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        adopt(f"bob/tasky@{sha}", "me/tasky", trust_remote_code=True, episodes=2, progress=False)
    card = (hub.api.snapshot_download("me/tasky", allow_patterns=["README.md"]) + "/README.md").replace("\\", "/")
    tokens = MarkdownIt("commonmark", {"html": True}).enable("table").parse(open(card).read())
    headings = [tokens[i + 1].content for i, t in enumerate(tokens) if t.type == "heading_open"]
    assert headings.count("Load it") == 1, headings
    assert not any("mallory" in t.content for t in tokens if t.type in ("fence", "code_block", "html_block"))
    inline = [c for t in tokens if t.type == "inline" for c in t.children or []]
    assert not any(c.type == "html_inline" for c in inline)
    [row] = [t for t in tokens if t.type == "inline" and "mallory" in t.content]
    assert any(c.type == "code_inline" and "mallory/evil" in c.content for c in row.children)  # shown, as text


def test_a_plain_repo_holding_bytecode_is_refused_before_consent_is_asked(hub_storing_bytecode, tmp_path, monkeypatch):
    """A plain repo with a harmless helper.py and, beside it, an unchecked-hash __pycache__/helper.*.pyc compiled from
    other source: the trust prompt listed helper.py, and with consent the bytecode ran instead (red-team finding, session
    29). A hub-envs repo's manifest refuses bytecode; a plain repo is held to the same rule."""
    import importlib.util
    import py_compile

    marker = tmp_path / "PWNED"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(marker))
    hidden = tmp_path / "hidden" / "helper.py"
    hidden.parent.mkdir()
    hidden.write_text("import os, pathlib\npathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('pwned')\n")
    pyc = py_compile.compile(
        str(hidden), cfile=str(tmp_path / "helper.pyc"), invalidation_mode=py_compile.PycInvalidationMode.UNCHECKED_HASH
    )
    env = (
        pr.REACH + pr.VECTOR_MAKE_ENV + "\nimport os, sys\nsys.path.insert(0, os.path.dirname(__file__))\nimport helper  # noqa\n"
    )
    folder = pr.write(tmp_path / "byte", {"env.py": env, "helper.py": "X = 1  # harmless\n"})
    (folder / Path(importlib.util.cache_from_source(str(folder / "helper.py")))).parent.mkdir(exist_ok=True)
    Path(importlib.util.cache_from_source(str(folder / "helper.py"))).write_bytes(Path(pyc).read_bytes())
    sha = upload(hub_storing_bytecode, "mallory/byte", folder)
    for consent in (False, True):
        with pytest.raises(InvalidRepoFormatError, match=r"compiled bytecode \(__pycache__/helper\..*\.pyc\)"):
            load_env(f"mallory/byte@{sha}", trust_remote_code=consent)
    assert not marker.exists()


def test_a_plain_repos_cached_snapshot_linking_out_of_the_cache_is_refused_and_dropped(hub, tmp_path):
    """The cache is not trusted: a snapshot file of a plain repo linking outside the cache's blobs/ (here to a stand-in
    for the Hub token) was hashed, and copied into the code folder a sandboxed env sees, while the sandbox hides HF_HOME
    (red-team finding, session 29). A hub-envs repo's load refuses such a link; a plain load does too."""
    from hub_envs.errors import IntegrityError
    from hub_envs.paths import hub_envs_home

    sha = upload(hub, "bob/linky", pr.vector_repo(tmp_path / "linky"))
    with pytest.warns(PlainRepoWarning):
        load_env(f"bob/linky@{sha}", trust_remote_code=True, check=False).unregister()
    secret = tmp_path / "token"
    secret.write_text("hf_not_for_env_code")
    snapshot = hub.hf_home / "hub" / "models--bob--linky" / "snapshots" / sha
    (snapshot / "notes.txt").symlink_to(secret)
    with pytest.raises(IntegrityError, match="notes.txt -> .*a link outside the cache's blobs/"):
        load_env(f"bob/linky@{sha}", trust_remote_code=True, check=False)
    assert not snapshot.exists() and secret.read_text() == "hf_not_for_env_code"  # the snapshot dropped, not the target
    assert not [p for p in (hub_envs_home() / "plain").rglob("notes.txt")]
    with pytest.warns(PlainRepoWarning):  # loads again from a fresh download
        load_env(f"bob/linky@{sha}", trust_remote_code=True, check=False).unregister()


def test_an_entry_file_whose_name_holds_an_adapter_placeholder_loads_as_that_file(hub, tmp_path):
    """The adapter was rendered by successive text replacements: an entry file named ``x"{{SOURCE_ENTRY}}".py`` had its
    name read again as a placeholder, and the adapter's source became Python of the file name's making (here a syntax
    error; with other names, an expression of its choosing) (red-team finding, session 29)."""
    name = 'x"{{SOURCE_ENTRY}}".py'
    sha = upload(hub, "bob/odd", pr.write(tmp_path / "odd", {name: pr.REACH + pr.VECTOR_MAKE_ENV}))
    with pytest.warns(PlainRepoWarning):
        loaded = load_env(f"bob/odd@{sha}:{name}", trust_remote_code=True)
    assert loaded.plain_source == f"bob/odd@{sha}:{name}"
    assert loaded.make().reset(seed=0)[0]["agent_pos"].shape == (2,)
    loaded.unregister()


def test_adopt_of_an_entry_file_named_outside_the_bmp_writes_a_readable_pyproject(hub, tmp_path):
    """adopt wrote pyproject.toml strings with json.dumps, whose surrogate-pair escapes TOML refuses: an entry file named
    with an emoji made the adoption fail on its own pyproject (red-team finding, session 29)."""
    from hub_envs.publishing.adopt import adopt

    name = "envs/Reach\U0001f916.py"
    sha = upload(hub, "bob/robot", pr.write(tmp_path / "robot", {name: pr.REACH + pr.VECTOR_MAKE_ENV}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = adopt(f"bob/robot@{sha}:{name}", "me/robot", trust_remote_code=True, episodes=2, progress=False)
    assert json.loads(open(hub.api.hf_hub_download("me/robot", "adopted_from.json", revision=result.sha)).read())["entry"] == name


def test_a_plain_load_bound_to_a_content_digest_refuses_other_content_and_takes_its_own(hub, tmp_path, monkeypatch):
    """``content_digest=`` (a Ray worker's binding to its driver's consent, #30 item 7) was dropped silently for a plain
    repo's ``user/name@sha:path``: a commit holding other files ran under consent given for other content (red-team
    finding, session 29)."""
    marker = tmp_path / "RAN"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(marker))
    payload = "\nimport os, pathlib\npathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('ran')\n"
    sha = upload(
        hub,
        "bob/bound",
        pr.write(
            tmp_path / "bound", {"envs/T.py": pr.REACH + pr.VECTOR_MAKE_ENV + payload, "env.py": pr.REACH + pr.VECTOR_MAKE_ENV}
        ),
    )
    for ref in (f"bob/bound@{sha}:envs/T.py", f"bob/bound@{sha}:env.py", f"bob/bound@{sha}"):
        with pytest.raises(UntrustedCodeError, match="not the content 0000000000000000… this load was bound to"):
            load_env(ref, trust_remote_code=True, content_digest="0" * 64)
    assert not marker.exists()
    with pytest.warns(PlainRepoWarning):
        digest = load_env(f"bob/bound@{sha}:envs/T.py", trust_remote_code=True, check=False).manifest.content_digest
    with pytest.warns(PlainRepoWarning):
        again = load_env(f"bob/bound@{sha}:envs/T.py", trust_remote_code=True, content_digest=digest, check=False)
    assert again.manifest.content_digest == digest


def test_the_source_a_worker_gets_of_a_plain_load_names_its_entry_file_and_digest(hub, tmp_path):
    """What the driver sends a worker (``EnvSource``, Ray's and the local backend's) named a plain load as
    ``user/name@<sha>`` only: bound to the commit's digest (red-team 29 fix above), a worker would make ``env.py``
    instead of the entry file the driver loaded."""
    from hub_envs.backends.base import EnvSource

    folder = pr.folder_repo(tmp_path / "twofold")
    (folder / "env.py").write_text(pr.REACH + pr.VECTOR_MAKE_ENV)  # another env, at the default entry
    sha = upload(hub, "bob/twofold", folder)
    with pytest.warns(PlainRepoWarning):
        far = load_env(f"bob/twofold@{sha}:envs/Far.py", trust_remote_code=True)
    source = EnvSource.from_loaded(far)
    assert source.ref == f"bob/twofold@{sha}:envs/Far.py" and source.content_digest == far.manifest.content_digest
    with pytest.warns(PlainRepoWarning):
        worker = source.load()
    assert worker.plain_source == far.plain_source and worker.gym_id == far.gym_id


def test_a_trusted_hub_envs_repo_loaded_by_an_entry_file_says_why_it_asks_again_not_that_the_endpoint_lies(hub, tmp_path):
    """`hub-envs trust` of a hub-envs repo binds its manifest's digest; loading that commit as a plain repo by an entry
    file hashes every file instead, so it asked again saying "the endpoint now serves other content under the same commit
    id. Do not trust it again", and told the user to run the `hub-envs trust` they had just run (red-team 29, TOFU)."""
    from helpers import TINY, copy_env

    from hub_envs import push_env

    result = push_env(copy_env(tmp_path, TINY), "bob/published", episodes=1, progress=False)
    assert cli(["trust", f"bob/published@{result.sha}"]) == 0
    load_env(f"bob/published@{result.sha}").unregister()  # consent holds for the hub-envs load
    with pytest.raises(UntrustedCodeError) as asked:
        load_env(f"bob/published@{result.sha}:tiny.py")
    said = str(asked.value)
    assert "is a hub-envs repo" in said and f'load_env("bob/published@{result.sha}")' in said, said
    assert "endpoint now serves" not in said and "hub-envs trust bob/published" not in said, said
