"""What names a repo, and what names a local folder: the red-team's input findings (issue 30, Low).

* A repo id with a trailing newline was accepted, three reports running: the Python API refused it only where it
  went through ``parse_repo_ref``, the commands' flags lost the newline in draccus' YAML reading and went on with
  ``user/name``, and the server stored a repo named ``name\\n``. Every entry that takes a repo id now applies one
  rule (:func:`hub_envs.repo.format.repo_id_problem`) and refuses with a ConfigError naming the value's ``repr`` and
  the rule; each entry is tested here.
* ``compare --policies=user/name`` took a same-named local folder for the caller's own checkpoint, without consent;
  policies now follow the envs' rule (:func:`hub_envs.repo.refs.local_path`): ``user/name`` always means the Hub.

Against one real loopback Hub per module, with a published env ``user/name``: on the old code, the ids below that lost
their newline loaded or listed that very repo.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import pytest
import requests
from helpers import TINY

from hub_envs import errors, push_env
from hub_envs.cli import main as cli_main
from hub_envs.repo.format import REPO_ID_RULE

BAD = "user/name\n"
SHOWN = repr(BAD)  # what the message shows: 'user/name\n', escaped


@pytest.fixture(scope="module")
def published(hub_module) -> str:
    return push_env(TINY, "user/name", episodes=1, progress=False).sha


def _api_entries(sha: str) -> dict:
    import hub_envs
    from hub_envs.repo import attestations as attestation

    return {
        "load_env": lambda: hub_envs.load_env(BAD, revision=sha, trust_remote_code=True, check=False),
        "push_env": lambda: hub_envs.push_env(TINY, BAD, episodes=1, progress=False),
        "trust": lambda: hub_envs.trust(BAD, sha),
        "untrust": lambda: hub_envs.untrust(BAD),
        "is_trusted": lambda: hub_envs.is_trusted(BAD, sha),
        "reproduce": lambda: hub_envs.reproduce(f"{BAD}@{sha}", trust_remote_code=True, workers=1, progress=False),
        "diff": lambda: hub_envs.diff(f"{BAD}@{sha}", f"user/name@{sha}", trust_remote_code=True, write=False),
        "compare --policies": lambda: hub_envs.compare(
            f"user/name@{sha}", policies=["random", BAD], episodes=2, trust_remote_code=True, progress=False
        ),
        "evaluate policy=": lambda: hub_envs.evaluate(
            f"user/name@{sha}", policy=f"{BAD}@{sha}", episodes=1, trust_remote_code=True, trust_policy_code=True
        ),
        "collect_attestations": lambda: attestation.collect_attestations(BAD),
        "merged_attestations": lambda: attestation.merged_attestations(BAD),
        "env_from_dataset": lambda: hub_envs.env_from_dataset(BAD),
    }


API_ENTRIES = sorted(_api_entries("0" * 40))


@pytest.mark.parametrize("entry", API_ENTRIES)
def test_every_python_entry_refuses_a_repo_id_with_a_trailing_newline(published, entry, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # whatever an entry would write lands here
    with pytest.raises(errors.ConfigError) as e, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _api_entries(published)[entry]()
    assert SHOWN in str(e.value) and REPO_ID_RULE in str(e.value), str(e.value)


def _cli_entries(sha: str) -> dict[str, list[str]]:
    return {
        "load --repo_id": ["load", f"--repo_id={BAD}", f"--revision={sha}", "--trust_remote_code=true", "--check=false"],
        "push --repo_id": ["push", f"--env_dir={TINY}", f"--repo_id={BAD}", "--episodes=1"],
        "trust": ["trust", f"{BAD}@{sha}"],
        "untrust": ["untrust", BAD],
        "reproduce --repo_id": ["reproduce", f"--repo_id={BAD}", f"--revision={sha}", "--trust_remote_code=true"],
        "evaluate --repo_id": ["evaluate", f"--repo_id={BAD}", f"--revision={sha}", "--episodes=1"],
        "evaluate --policy": ["evaluate", f"--repo_id=user/name@{sha}", f"--policy={BAD}@{sha}", "--episodes=1"],
        "compare --repo_id": ["compare", f"--repo_id={BAD}", f"--revision={sha}", "--policies=random,random"],
        "compare --policies": ["compare", f"--repo_id=user/name@{sha}", f"--policies=random,{BAD}", "--episodes=2"],
        "diff --old": ["diff", f"--old={BAD}@{sha}", f"--new=user/name@{sha}"],
        "attestations --repo_id": ["attestations", f"--repo_id={BAD}"],
        "eval --env.repo_id": ["eval", "--env.type=hub", f"--env.repo_id={BAD}", f"--env.revision={sha}"],
        "train --env.type": ["train", f"--env.type={BAD.strip()}@{sha[:12]}\n", "--steps=1"],
    }


CLI_ENTRIES = sorted(_cli_entries("0" * 40))


@pytest.mark.parametrize("entry", CLI_ENTRIES)
def test_every_command_refuses_a_repo_flag_with_a_trailing_newline(published, entry, tmp_path, monkeypatch, capsys):
    """draccus reads a flag's value as YAML, which dropped the newline: the command went on with ``user/name``."""
    monkeypatch.chdir(tmp_path)
    code = cli_main(_cli_entries(published)[entry])
    err = capsys.readouterr().err
    assert code != 0 and "ConfigError" in err, err[-2000:]
    assert "\\n'" in err, err[-2000:]  # the value as given, its newline shown


def test_the_server_refuses_a_repo_name_with_a_trailing_newline(hub_module):
    """huggingface_hub 0.35 sends it (its check ends in ``$``); the server's own check did the same and stored it."""
    r = requests.post(
        f"{hub_module.endpoint}/api/repos/create", json={"type": "model", "name": "name\n", "organization": "user"}, timeout=30
    )
    assert r.status_code == 400 and "Invalid repo id" in r.text, r.text
    assert "name\n" not in [m.id.split("/")[1] for m in hub_module.api.list_models(author="user")]


def test_a_manifest_repo_id_with_a_trailing_newline_is_refused(tmp_path):
    from hub_envs.repo.format import MANIFEST_FILE, Manifest

    data = json.loads(_published_manifest_text())
    data["repo_id"] = BAD
    (tmp_path / MANIFEST_FILE).write_text(json.dumps(data))
    with pytest.raises(errors.ManifestError, match=re.escape(REPO_ID_RULE)):
        Manifest.read(tmp_path, where="x")


def _published_manifest_text() -> str:
    """A valid manifest: the tiny env's, as push_env writes it (read from the module's published repo)."""
    from huggingface_hub import hf_hub_download

    from hub_envs.repo.format import MANIFEST_FILE

    return Path(hf_hub_download("user/name", MANIFEST_FILE)).read_text()


# --- compare --policies: a local folder is written as a path ------------------------------------------------


@pytest.fixture
def policy_repo_and_folder(hub_module, tmp_path, monkeypatch) -> str:
    """``mallory/policy`` on the Hub, and a folder ``mallory/policy`` in the working directory (a checkpoint the
    caller's code would load as its own)."""
    api = hub_module.api
    api.create_repo("mallory/policy", exist_ok=True)
    sha = api.upload_file(path_or_fileobj=b'{"type": "act"}', path_in_repo="config.json", repo_id="mallory/policy").oid
    folder = tmp_path / "mallory" / "policy"
    folder.mkdir(parents=True)
    (folder / "config.json").write_text('{"type": "act"}')
    monkeypatch.chdir(tmp_path)
    return sha


def test_compare_takes_user_name_from_the_hub_even_when_a_folder_of_that_name_exists(policy_repo_and_folder):
    from hub_envs.operations.compare import policy_spec

    with pytest.warns(UserWarning, match=r"'\./mallory/policy'"):
        spec = policy_spec("mallory/policy")
    assert spec == {"type": "lerobot", "checkpoint": f"mallory/policy@{policy_repo_and_folder}"}


@pytest.mark.parametrize("written", ["./mallory/policy", "ABS", "mallory/policy/", "PATH"])
def test_compare_takes_a_folder_written_as_a_path(policy_repo_and_folder, tmp_path, written):
    from hub_envs.operations.compare import policy_spec

    folder = tmp_path / "mallory" / "policy"
    given = {"ABS": str(folder), "PATH": folder}.get(written, written)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "taken from the Hub" warning: it is a path
        spec = policy_spec(given)  # type: ignore[arg-type]
    assert spec == {"type": "lerobot", "path": str(folder.resolve())}


def test_envs_and_policies_share_one_rule_for_local_folders(policy_repo_and_folder, tmp_path):
    """The same text means the same thing to load_env and to compare: ``user/name`` the Hub, a path a folder; a bare
    name or a deeper relative path (``outputs/train/.../pretrained_model``, which no repo id looks like) a folder
    when one exists."""
    from hub_envs.repo.refs import local_path

    deep = tmp_path / "outputs" / "train" / "pretrained_model"
    deep.mkdir(parents=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert local_path("mallory/policy") is None
    assert local_path("./mallory/policy") == Path("./mallory/policy")
    assert local_path("outputs/train/pretrained_model") == Path("outputs/train/pretrained_model")
    assert local_path("mallory") == Path("mallory")
    assert local_path("nothing-here") is None and local_path("user/name@main") is None
    with pytest.raises(errors.ConfigError, match=r"write '\./outputs/train '"):
        (tmp_path / "outputs" / "train ").mkdir()
        local_path("outputs/train ")
