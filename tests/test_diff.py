"""``hub-envs diff`` against a real loopback Hub: a revision against itself, changed dynamics, a README-only
change, and a changed observation shape. One server and one tiny env repo for the module; each test
publishes its own revisions."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import TINY, copy_env, republish

from hub_envs import diff, errors, push_env
from hub_envs.cli import main as cli_main
from hub_envs.envcode.registration import snapshot_registries


def _push(path, repo_id):
    return push_env(path, repo_id, episodes=2, progress=False)


def _published_benchmark(sha: str) -> dict:
    from huggingface_hub import hf_hub_download

    return json.loads(Path(hf_hub_download("alice/tiny", "hub_env.json", revision=sha)).read_text())["benchmarks"][0]


@pytest.fixture(scope="module")
def base(hub_module):
    """alice/tiny, published once: (Hub, sha)."""
    return hub_module, _push(TINY, "alice/tiny").sha


def test_a_revision_against_itself_is_identical_and_exits_0(base, tmp_path, capsys):
    _hub, sha = base
    before = snapshot_registries()
    code = cli_main(
        ["diff", f"--old=alice/tiny@{sha}", f"--new=alice/tiny@{sha}", "--trust_remote_code=true", f"--out={tmp_path}"]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    assert "IDENTICAL BEHAVIOUR" in out and "no file differs" in out
    assert snapshot_registries() == before  # both loads unregistered
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["behaviour_identical"] and report["manifest"] == [] and report["spaces"] == []
    assert [s["source"] for s in report["seeds"]] == ["recorded actions of episode 0", "recorded actions of episode 1"] + [
        "random actions"
    ] * 2
    assert [s["seed"] for s in report["seeds"]] == [0, 1, 2, 3]  # random actions on seeds the dataset did not replay
    assert not any(s["diverged"] for s in report["seeds"])
    assert report["fingerprint"]["same"] and report["fingerprint"]["live_old"] == report["fingerprint"]["recorded_old"]
    assert report["deltas"]["return"]["mean"] == 0.0 and report["deltas"]["return"]["ci"] == [0.0, 0.0]
    # the declared random-policy benchmark, re-run on both: the old side reproduces what was published, paired delta 0
    (bench,) = report["benchmarks"]
    assert bench["name"] == "random-policy" and bench["episodes_differing"] == [] and bench["declared_in_new"]
    published = _published_benchmark(sha)
    assert bench["seeds"] == published["seeds"]
    assert bench["metrics"]["mean_return"]["per_episode_old"] == published["per_episode"]["return"]
    assert bench["metrics"]["mean_return"]["mean"] == 0.0 and bench["metrics"]["mean_return"]["ci"] == [0.0, 0.0]
    assert "Benchmark random-policy (policy random, 2 episodes):" in out and "paired delta +0 [95% CI +0, +0]" in out
    assert report["old"]["sha"] == sha and report["provenance"]["hub_envs_version"]
    assert "# hub-envs diff" in (tmp_path / "report.md").read_text()


def test_changed_dynamics_exit_1_naming_the_first_divergent_step_and_feature(base, tmp_path, capsys):
    hub, old = base
    stronger = copy_env(tmp_path, edits={"dynamics.py": lambda t: t.replace("GAIN = 1.0\n", "GAIN = 1.05\n")})
    new = _push(stronger, "alice/tiny").sha
    code = cli_main(
        ["diff", f"--old=alice/tiny@{old}", f"--new=alice/tiny@{new}", "--trust_remote_code=true", f"--out={tmp_path / 'o'}"]
    )
    out = capsys.readouterr().out
    assert code == 1, out
    assert "BEHAVIOUR DIFFERS" in out and "code: ~1 changed (dynamics.py)" in out
    assert "seed 0 (recorded actions of episode 0): next.reward diverged at step 0" in out
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    first = report["first_divergence"]
    assert (first["seed"], first["step"], first["feature"]) == (0, 0, "next.reward")
    # both values are the real ones: the reward after the first push, with each gain
    assert first["old"] != first["new"] and first["max_abs_diff"] == pytest.approx(abs(first["new"] - first["old"]))
    by_seed = {(s["source"], s["seed"]): s for s in report["seeds"]}
    assert all(s["diverged"] for s in by_seed.values())
    assert "observation.state" in by_seed[("recorded actions of episode 0", 0)]["errors"]
    assert not report["fingerprint"]["same"]
    # the benchmark's paired delta: the old side is the published result, the new side each episode's new return
    ret = report["benchmarks"][0]["metrics"]["mean_return"]
    assert ret["per_episode_old"] == _published_benchmark(old)["per_episode"]["return"]
    paired = [n - o for o, n in zip(ret["per_episode_old"], ret["per_episode_new"], strict=True)]
    assert all(d != 0 for d in paired) and report["benchmarks"][0]["episodes_differing"] == [0, 1]
    assert ret["mean"] == pytest.approx(sum(paired) / 2) and min(paired) <= ret["ci"][0] <= ret["ci"][1] <= max(paired)
    assert "| random-policy (policy random, 2 episodes) | mean_return |" in (tmp_path / "o" / "report.md").read_text()
    assert any(c["field"] == "code_digest" or c["field"].startswith("dataset.") for c in report["manifest"])
    try:  # the PNG exists exactly when matplotlib does
        import matplotlib  # noqa: F401
    except ImportError:
        assert not (tmp_path / "o" / "report.png").exists()
    else:
        assert (tmp_path / "o" / "report.png").is_file()
    # two different repos compare the same way (the old one's recorded actions drive both)
    other = _push(stronger, "bob/tiny-stronger").sha
    across = diff(f"alice/tiny@{old}", f"bob/tiny-stronger@{other}", trust_remote_code=True, write=False, random_episodes=0)
    assert across.exit_code == 1 and len(across.seeds) == 2 and across.new["repo_id"] == "bob/tiny-stronger"
    assert (across.first_divergence.step, across.first_divergence.feature) == (0, "next.reward")
    assert across.files["code"]["changed"] == ["dynamics.py"]


def test_a_readme_only_change_exits_0_with_the_file_listed(base, tmp_path, capsys):
    hub, _ = base
    old = _push(TINY, "alice/tiny-docs").sha

    def edit_readme(folder: Path) -> None:
        (folder / "README.md").write_text((folder / "README.md").read_text() + "\nA typo fixed.\n")

    new = republish(hub.api, "alice/tiny-docs", edit_readme, message="docs")
    code = cli_main(
        ["diff", f"--old=alice/tiny-docs@{old}", f"--new=alice/tiny-docs@{new}", "--trust_remote_code=true", f"--out={tmp_path}"]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    assert "generated: ~2 changed (README.md, hub_env.json)" in out, out
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["files"] == {"generated": {"added": [], "removed": [], "changed": ["README.md", "hub_env.json"]}}
    assert report["behaviour_identical"]


def test_a_changed_observation_shape_is_reported_as_a_space_change(base, tmp_path, capsys):
    _hub, old = base
    wider = copy_env(
        tmp_path,
        edits={
            "tiny.py": lambda t: (
                t.replace("spaces.Box(-2.0, 2.0, (2,), np.float32)", "spaces.Box(-2.0, 2.0, (3,), np.float32)")
                .replace("[self.pos[0], self.vel[0]]", "[self.pos[0], self.vel[0], 0.0]")
                .replace("PolicyFeature(type=FeatureType.STATE, shape=(2,))", "PolicyFeature(type=FeatureType.STATE, shape=(3,))")
            )
        },
    )
    new = _push(wider, "alice/tiny").sha
    report = diff(f"alice/tiny@{old}", f"alice/tiny@{new}", trust_remote_code=True, out=tmp_path / "o")
    assert report.exit_code == 1
    assert {"space": "observation_space", "field": "agent_pos.shape", "old": [2], "new": [3]} in report.spaces
    assert any(c["field"].startswith("dataset.features") for c in report.manifest)
    # the rest of the behaviour is still compared: same dynamics, so rewards and flags agree
    assert report.seeds and not report.diverged
    assert "SPACE CHANGE observation_space agent_pos.shape: [2] -> [3]" in report.summary()
    # the CLI says so too and exits 1, not 2
    assert (
        cli_main(
            [
                "diff",
                f"--old=alice/tiny@{old}",
                f"--new=alice/tiny@{new}",
                "--trust_remote_code=true",
                "--episodes=0",
                "--random_episodes=1",
                f"--out={tmp_path}",
            ]
        )
        == 1
    )
    assert "SPACE CHANGE" in capsys.readouterr().out


def test_bad_input_exits_2_with_a_typed_error(base, capsys):
    _hub, sha = base
    assert cli_main(["diff", f"--old=alice/tiny@{sha}"]) == 2
    assert "needs --old=" in capsys.readouterr().err
    assert cli_main(["diff", f"--old=alice/tiny@{sha}", "--new=alice/nothing-here", "--trust_remote_code=true"]) == 2
    err = capsys.readouterr().err
    assert "alice/nothing-here" in err and "error:" in err
    with pytest.raises(errors.ConfigError, match="episodes=-1"):
        diff(f"alice/tiny@{sha}", f"alice/tiny@{sha}", episodes=-1, write=False)


def test_a_changed_action_shape_is_a_space_change_and_no_episode_is_forced(base, tmp_path):
    _hub, old = base
    two_forces = copy_env(
        tmp_path,
        edits={
            "tiny.py": lambda t: (
                t.replace("spaces.Box(-1.0, 1.0, (1,), np.float32)", "spaces.Box(-1.0, 1.0, (2,), np.float32)")
                .replace("np.asarray(action, dtype=np.float64)", "np.asarray(action, dtype=np.float64)[:1]")
                .replace(
                    "PolicyFeature(type=FeatureType.ACTION, shape=(1,))", "PolicyFeature(type=FeatureType.ACTION, shape=(2,))"
                )
            )
        },
    )
    new = _push(two_forces, "alice/tiny-actions").sha
    report = diff(f"alice/tiny@{old}", f"alice/tiny-actions@{new}", trust_remote_code=True, write=False)
    assert report.exit_code == 1
    assert {"space": "action_space", "field": "shape", "old": [1], "new": [2]} in report.spaces
    assert report.seeds == [] and any("action space changed" in n for n in report.notes)


def test_diff_help_imports_neither_torch_nor_lerobot():
    code = (
        "import sys\nfrom hub_envs.cli import main\ntry:\n    main(['diff', '--help'])\nexcept SystemExit:\n    pass\n"
        "print('HEAVY', sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'lerobot', 'gymnasium')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "HEAVY []" in out.stdout and "--random_episodes" in out.stdout, out.stdout[-500:] + out.stderr[-500:]


def test_an_isolated_diff_finds_what_the_in_process_diff_finds(base, tmp_path):
    """--isolation=process: both revisions step in worker processes, and the report is the same."""
    _hub, old = base
    stronger = copy_env(tmp_path, edits={"dynamics.py": lambda t: t.replace("GAIN = 1.0\n", "GAIN = 1.1\n")})
    new = _push(stronger, "alice/tiny").sha
    reports = [
        diff(f"alice/tiny@{old}", f"alice/tiny@{new}", trust_remote_code=True, write=False, isolation=isolation)
        for isolation in ("none", "process")
    ]
    here, isolated = (r.to_dict() for r in reports)
    assert isolated["settings"]["isolation"] == "process" and here["settings"]["isolation"] == "none"
    assert isolated["first_divergence"] == here["first_divergence"] and isolated["first_divergence"]["step"] == 0
    for key in ("seeds", "benchmarks", "deltas", "fingerprint", "spaces", "manifest"):
        assert isolated[key] == here[key], key
    assert reports[1].exit_code == 1
