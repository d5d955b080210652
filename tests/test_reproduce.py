"""The reproducibility harness: fingerprints on load, replay of the dataset, benchmark reproduction,
provenance, env_from_dataset, and the reports of ``hub-envs reproduce``.

A *perturbed env* is a published repo whose code changed (a physics constant) while its dataset and
benchmark stayed as published; integrity passes (the manifest's hashes are fixed up, as a careless
publisher's hand-made commit would). push_env cannot make one: it regenerates the dataset from the
new code. A *modified dataset* is the same repo with one recorded value changed.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from helpers import TINY, build_wheel, comparable_report, copy_env, install_wheels, republish

from hub_envs import env_from_dataset, errors, load_env, push_env, reproduce, trust
from hub_envs.cli import main as cli_main
from hub_envs.dataset.reader import read_episode_frames
from hub_envs.envcode.registration import snapshot_registries
from hub_envs.harness.benchmark import bootstrap_ci, reproduce_benchmark
from hub_envs.harness.replay import replay_dataset

ENVS = Path(__file__).resolve().parent.parent / "envs"


def _push(path, repo_id, **kw):
    kw.setdefault("episodes", 2)
    kw.setdefault("progress", False)
    return push_env(path, repo_id, **kw)


def _perturb_gain(folder: Path) -> None:
    """A changed physics constant: the force gain of the tiny env's dynamics, 1.0 -> 1.05."""
    path = folder / "dynamics.py"
    text = path.read_text()
    assert "GAIN = 1.0\n" in text
    path.write_text(text.replace("GAIN = 1.0\n", "GAIN = 1.05\n"))


def _edit_dataset_value(folder: Path, key: str, episode: int, frame: int, element: int, delta: float) -> None:
    """Change one recorded value in the dataset's parquet, keeping its schema (and LeRobot's metadata)."""
    path = next((folder / "dataset" / "data").rglob("*.parquet"))
    table = pq.read_table(path)
    rows = np.flatnonzero(
        (table.column("episode_index").to_numpy() == episode) & (table.column("frame_index").to_numpy() == frame)
    )
    assert len(rows) == 1
    values = table.column(key).to_pylist()
    values[int(rows[0])][element] += delta
    i = table.schema.get_field_index(key)
    table = table.set_column(i, table.schema.field(i), pa.array(values, type=table.schema.field(i).type))
    pq.write_table(table, path)


# --- the example envs reproduce their own datasets -----------------------------------------------


def _reach_small(tmp_path: Path) -> Path:
    return copy_env(
        tmp_path,
        ENVS / "reach",
        "reach",
        edits={"config.py": lambda s: s.replace("episode_length: int = 100", "episode_length: int = 12")},
    )


@pytest.mark.parametrize("name", ["pendulum", "hover", "reach"])
def test_each_example_env_reproduces_its_own_pushed_dataset_exactly(hub, tmp_path, name, monkeypatch):
    from helpers import saved_figures

    import hub_envs.harness.report

    if not (ENVS / name).is_dir():
        pytest.skip(f"envs/{name} is not there")
    folder = _reach_small(tmp_path) if name == "reach" else ENVS / name
    pushed = _push(folder, f"alice/{name}", video=False)  # PNG images: exact (tests/test_video.py: the video default)
    figures = saved_figures(monkeypatch, hub_envs.harness.report)
    before = snapshot_registries()
    report = reproduce(
        f"alice/{name}", revision=pushed.sha, trust_remote_code=True, workers=1, out=tmp_path / "out", progress=False
    )
    assert snapshot_registries() == before  # reproduce leaves no registration behind
    assert report.reproduced, report.summary()
    assert report.sha == pushed.sha
    replay = report.replay
    assert replay.ok and replay.tolerance == 0.0
    assert [e.episode for e in replay.episodes] == [0, 1] and [e.seed for e in replay.episodes] == [0, 1]
    assert sum(e.length for e in replay.episodes) == pushed.manifest.dataset["frames"]
    assert {"observation.state", "next.reward", "next.done", "next.success", "env_state"} <= set(replay.features)
    if name == "reach":  # the camera image is compared too, pixel for pixel
        assert "observation.image" in replay.features
    assert all(v == 0.0 for e in replay.episodes for v in e.max_abs_diff.values())
    (bench,) = report.benchmarks
    assert bench.passed and bench.name == "random-policy"
    assert bench.reproduced_per_episode["return"] == pytest.approx(bench.published_per_episode["return"], abs=0)
    assert report.fingerprint["ok"]
    # the card shows the same benchmark as model-index evaluation results
    card = hub.api.model_info(f"alice/{name}", revision=pushed.sha).card_data
    assert {e.metric_type: e.metric_value for e in card.eval_results} == pytest.approx(pushed.manifest.benchmarks[0]["metrics"])
    # provenance: sha, digests, seeds and versions beside the published ones
    prov = report.provenance
    assert prov["sha"] == pushed.sha and prov["code_digest"] == pushed.manifest.code_digest == prov["dataset_code_digest"]
    assert prov["dataset_fingerprint"] == prov["published_dataset_fingerprint"] == pushed.manifest.dataset["fingerprint"]
    assert prov["seeds"]["dataset"] == [0, 1]
    assert {"python", "numpy", "gymnasium", "torch", "lerobot"} <= set(prov["versions_here"])
    if name in ("hover", "reach"):
        assert "pybullet" in prov["versions_here"] and "pybullet" in prov["versions_published"]
    assert prov["version_differences"] == {}
    # the three reports
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    assert data["reproduced"] is True and data["sha"] == pushed.sha and data["replay"]["episodes_diverged"] == []
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert "**REPRODUCED**" in markdown and pushed.sha in markdown
    assert (tmp_path / "out" / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # no video feature (reach's camera is stored as PNG images here): no video panel, no tolerance line
    (fig,) = figures
    assert replay.video is None and [ax.get_title() for ax in fig.axes] == ["benchmark random-policy: per-episode returns (pass)"]
    assert not any(line.get_label().startswith("tolerance") for ax in fig.axes for line in ax.get_lines())


# --- a perturbed env --------------------------------------------------------------------------


def test_a_perturbed_env_is_caught_by_the_fingerprint_replay_and_benchmark(hub, tmp_path, capsys):
    pushed = _push(TINY, "alice/tiny")

    def perturb_and_claim_other_versions(folder: Path) -> None:
        _perturb_gain(folder)
        manifest = json.loads((folder / "hub_env.json").read_text())
        manifest["versions"]["numpy"] = "1.26.0"  # as if published with another numpy
        (folder / "hub_env.json").write_text(json.dumps(manifest))

    sha = republish(hub.api, "alice/tiny", perturb_and_claim_other_versions, message="stronger motor")
    assert sha != pushed.sha

    # 1. the fingerprint on load: error / warn / off, with the version differences
    before = snapshot_registries()
    with pytest.raises(errors.FingerprintMismatchError) as e:
        load_env(f"alice/tiny@{sha}", trust_remote_code=True)
    assert "seeds [0, 1] no longer match" in str(e.value) and "hub-envs reproduce" in str(e.value)
    assert "numpy 1.26.0 (published) vs" in str(e.value)
    assert snapshot_registries() == before
    with pytest.warns(UserWarning, match="golden-rollout fingerprint drifted"):
        warned = load_env(f"alice/tiny@{sha}", trust_remote_code=True, fingerprint="warn")
    assert warned.report.fingerprint.startswith("DRIFTED")
    warned.unregister()
    off = load_env(f"alice/tiny@{sha}", trust_remote_code=True, fingerprint="off")
    assert off.report.fingerprint == "off"
    off.unregister()

    # 2. the replay names the episode, step and feature; 3. the benchmark fails
    report = reproduce("alice/tiny", revision=sha, trust_remote_code=True, workers=1, out=tmp_path / "out", progress=False)
    assert not report.reproduced
    assert report.checks == {"replay": False, "benchmark random-policy": False, "fingerprint": False}
    replay = report.replay
    assert [e.episode for e in replay.diverged] == [0, 1]
    first = replay.first_divergence
    # frame 0 holds the reset observation (unchanged) and the reward of the first, now stronger, push
    assert (first.episode, first.seed, first.step, first.feature) == (0, 0, 0, "next.reward")
    by_feature = {d.feature: d for d in replay.episodes[0].divergences}
    assert by_feature["observation.state"].step == 1 and by_feature["env_state"].step == 1
    assert by_feature["observation.state"].env_key == "agent_pos"
    assert "next.done" not in by_feature and "next.success" not in by_feature or by_feature["next.success"].step >= 1
    # the reported difference is the real one: replay the perturbed physics by hand
    frames = read_episode_frames(report_dataset(report), 0)
    pos0, action0 = float(frames["observation.state"][0][0]), float(frames["action"][0][0])
    vel_perturbed = np.clip(1.05 * 0.05 * action0, -2, 2)
    expected_reward = -abs(np.clip(pos0 + 0.05 * vel_perturbed, -1, 1))
    assert by_feature["next.reward"].replay == pytest.approx(expected_reward, abs=1e-6)
    assert by_feature["next.reward"].dataset == pytest.approx(float(frames["next.reward"][0][0]))
    # localized from the recorded states: the dynamics differ from the very first step
    loc = replay.episodes[0].localization
    assert loc["first_step"] == 0 and "playback diverged by" in loc["message"]
    (bench,) = report.benchmarks
    assert not bench.passed and bench.episodes_differing == [0, 1]
    assert {m.name: m.passed for m in bench.metrics}["mean_return"] is False
    # provenance: the version difference, and the code that recorded the data
    assert report.provenance["version_differences"]["numpy"][0] == "1.26.0"
    assert any("other code" in n for n in report.notes)
    summary = report.summary()
    assert (
        "episode 0 (seed 0), next.reward: playback diverged by" in summary
        and "at step 0" in summary
        and "numpy 1.26.0 (published)" in summary
    )
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert "**NOT REPRODUCED**" in markdown and "| numpy | 1.26.0 |" in markdown and "**differs**" in markdown

    # the CLI: exit 1, says where the reports are
    code = cli_main(
        [
            "reproduce",
            "--repo_id=alice/tiny",
            f"--revision={sha}",
            "--trust_remote_code=true",
            f"--out={tmp_path / 'cli'}",
            "--workers=1",
        ]
    )
    out = capsys.readouterr().out
    assert code == 1
    assert "NOT REPRODUCED" in out and f"Reports: {tmp_path / 'cli' / 'report.md'}" in out
    assert json.loads((tmp_path / "cli" / "report.json").read_text())["replay"]["first_divergence"]["feature"] == "next.reward"
    # and the published revision still reproduces, exit 0
    assert (
        cli_main(["reproduce", f"--repo_id=alice/tiny@{pushed.sha}", "--trust_remote_code=true", f"--out={tmp_path / 'ok'}"]) == 0
    )
    # a hub-envs error is exit 1 with the message
    assert cli_main(["reproduce", "--repo_id=nobody/nothing", "--trust_remote_code=true", f"--out={tmp_path / 'x'}"]) == 1
    assert "EnvRepoNotFoundError" in capsys.readouterr().err


def _sim_env(tmp_path: Path) -> tuple[Path, Path, Path, Path]:
    """Real distributions and the env that needs them: the env requires ``hub-envs-fixture-sim`` 1.0, which requires
    ``hub-envs-fixture-physics``, whose force gain is 1.0 in version 1.0 and 1.05 in 1.1 (as mujoco is to metaworld).
    Returns (the folder of wheels, the publisher's site folder (physics 1.0), this machine's (1.1), the env folder)."""
    wheels = tmp_path / "wheels"
    sim = "from hub_envs_fixture_physics import GAIN\n\n\ndef gain():\n    return GAIN\n"
    build_wheel(
        wheels, "hub-envs-fixture-sim", "1.0", {"hub_envs_fixture_sim/__init__.py": sim}, ("hub-envs-fixture-physics>=1.0",)
    )
    for version, gain in (("1.0", "1.0"), ("1.1", "1.05")):
        build_wheel(wheels, "hub-envs-fixture-physics", version, {"hub_envs_fixture_physics/__init__.py": f"GAIN = {gain}\n"})
    sites = [
        install_wheels(wheels, tmp_path / site, "hub-envs-fixture-sim==1.0", f"hub-envs-fixture-physics=={version}")
        for site, version in (("publisher-site", "1.0"), ("here-site", "1.1"))
    ]
    env = copy_env(
        tmp_path,
        name="sim_env",
        edits={
            "dynamics.py": lambda t: t.replace(
                "import numpy as np\n", "import numpy as np\nfrom hub_envs_fixture_sim import gain\n"
            ).replace("GAIN = 1.0\n", "GAIN = gain()\n"),
            "pyproject.toml": lambda t: t.replace('"numpy>=1.26"]', '"numpy>=1.26", "hub-envs-fixture-sim>=1.0"]'),
        },
    )
    # a venv worker holds the env's requirements, not lerobot: the config class goes to a module of its own
    code = (env / "tiny.py").read_text()
    env_part, config_part = code.split("@dataclass\n", 1)
    (env / "tiny.py").write_text(
        env_part.replace("from lerobot.configs.types import FeatureType, PolicyFeature\n", "")
        .replace("from lerobot.envs.configs import EnvConfig\n", "")
        .replace("from dataclasses import dataclass, field\n", "")
    )
    (env / "config.py").write_text(
        "from dataclasses import dataclass, field\n\nfrom lerobot.configs.types import FeatureType, PolicyFeature\n"
        "from lerobot.envs.configs import EnvConfig\n\n\n@dataclass\n" + config_part
    )
    project = env / "pyproject.toml"
    project.write_text(project.read_text().replace('config = "tiny:TinyEnvConfig"', 'config = "config:TinyEnvConfig"'))
    return wheels, sites[0], sites[1], env


def _machine(tmp_path: Path, name: str, site: Path, wheels: Path):
    """``hub-envs`` on another machine: its own HF_HOME and hub-envs home, ``site`` on its PYTHONPATH, uv finding the
    fixture distributions in ``wheels`` (as it would find them on an index)."""

    def run(*args: str) -> subprocess.CompletedProcess:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGING_FACE_", "HUB_ENVS_"))}
        env.update(
            HF_ENDPOINT=os.environ["HF_ENDPOINT"],
            HF_HOME=str(tmp_path / f"{name}-home"),
            HUB_ENVS_HOME=str(tmp_path / f"{name}-hub-envs"),
            HF_HUB_DISABLE_TELEMETRY="1",
            HF_HUB_DISABLE_XET="1",
            HF_HUB_DISABLE_PROGRESS_BARS="1",
            UV_FIND_LINKS=str(wheels),
            PYTHONPATH=os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])]),
        )
        return subprocess.run(
            [sys.executable, "-m", "hub_envs.cli", *args], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=900
        )

    return run


def test_a_differing_dependency_is_blamed_first_and_the_publishers_versions_reproduce(hub, tmp_path):
    """Issue 29: an env published with mujoco 3.3.0 was NOT REPRODUCED with 3.3.7, and the report blamed draccus,
    lerobot, torch... but never mujoco, which only the manifest's ``resolved`` records. Here the simulator behind
    the env's requirement really differs (physics 1.0 at the publisher, 1.1 here); the stack around it (draccus,
    lerobot, torch) is recorded as another stack's. The report ranks the dependency first and names the command that runs
    it with the publisher's versions, which reproduces (a real venv, built by uv from the recorded versions)."""
    wheels, publisher_site, here_site, env_dir = _sim_env(tmp_path)
    publisher = _machine(tmp_path, "publisher", publisher_site, wheels)
    pushed = publisher("push", f"--env_dir={env_dir}", "--repo_id=alice/sim", "--episodes=2", "--workers=1", "--video=false")
    assert pushed.returncode == 0, pushed.stdout[-2000:] + pushed.stderr[-2000:]

    def as_another_stack(folder: Path) -> None:
        manifest = json.loads((folder / "hub_env.json").read_text())
        assert (
            manifest["resolved"]["hub-envs-fixture-physics"] == "1.0" and "hub-envs-fixture-physics" not in manifest["versions"]
        )
        manifest["versions"].update({"draccus": "0.9.3", "lerobot": "0.3.3", "torch": "2.7.1"})
        (folder / "hub_env.json").write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")

    sha = republish(hub.api, "alice/sim", as_another_stack, message="as published on another stack")

    here = _machine(tmp_path, "here", here_site, wheels)
    run = here("reproduce", "--repo_id=alice/sim", f"--revision={sha}", "--trust_remote_code=true", "--workers=1", "--out=first")
    assert run.returncode == 1, run.stdout[-3000:] + run.stderr[-3000:]
    assert run.stdout.startswith(f"NOT REPRODUCED: alice/sim@{sha}") and "next.reward" in run.stdout
    stack = next(line for line in run.stdout.splitlines() if line.strip().startswith("stack:")).strip()
    assert stack.startswith(
        "stack: versions differ from the publisher's: hub-envs-fixture-physics 1.0 (published) vs 1.1 (here, a dependency "
        "of its requirements), "
    ), stack
    assert stack.index("hub-envs-fixture-physics") < stack.index("draccus 0.9.3") < stack.index("lerobot 0.3.3")
    report = json.loads((tmp_path / "first" / "report.json").read_text())
    drift = report["provenance"]["version_drift"]  # ranked: the dependency first, then the stack
    assert [(d["package"], d["kind"]) for d in drift] == [
        ("hub-envs-fixture-physics", "dependency"),
        ("draccus", "stack"),
        ("lerobot", "stack"),
        ("torch", "stack"),
    ]
    assert drift[0]["published"] == "1.0" and drift[0]["here"] == "1.1"
    markdown = (tmp_path / "first" / "report.md").read_text()
    assert (
        "## Versions that differ" in markdown
        and "| hub-envs-fixture-physics | 1.0 | 1.1 | a dependency of its requirements |" in markdown
    )

    command = next(line for line in run.stdout.splitlines() if "with the publisher's versions, run:" in line)
    command = command.split("run: ", 1)[1]
    assert command == (
        f"hub-envs reproduce --repo_id=alice/sim --revision={sha} --trust_remote_code=true --isolation=venv --versions=publisher"
    )
    args = shlex.split(command)[2:]
    again = here("reproduce", *args, "--workers=1", "--out=again")
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert again.stdout.startswith(f"REPRODUCED: alice/sim@{sha}") and "with the publisher's versions, run" not in again.stdout
    worker = json.loads((tmp_path / "again" / "report.json").read_text())["provenance"]
    assert "hub-envs-fixture-physics==1.0" in worker["worker"]["installed"]
    assert [d["package"] for d in worker["version_drift"]] == ["draccus", "lerobot", "torch"]  # the env's own: the publisher's


def report_dataset(report) -> Path:
    """The snapshot dataset a report replayed (found through the cache, as a user would)."""
    loaded = load_env(f"{report.repo_id}@{report.sha}", trust_remote_code=True, check=False)
    loaded.unregister()
    return loaded.dataset_root


def test_results_are_identical_with_1_and_2_workers(hub, tmp_path):
    _push(TINY, "alice/tiny-workers", episodes=4)
    sha = republish(hub.api, "alice/tiny-workers", _perturb_gain)
    one = reproduce("alice/tiny-workers", revision=sha, trust_remote_code=True, workers=1, out=tmp_path / "w1", progress=False)
    two = reproduce("alice/tiny-workers", revision=sha, trust_remote_code=True, workers=2, out=tmp_path / "w2", progress=False)
    assert len(one.replay.diverged) == 4 and one.replay.diverged[0].error_curve  # something substantial to compare
    assert comparable_report(one) == comparable_report(two)


# --- a modified dataset ------------------------------------------------------------------------


def test_a_modified_dataset_is_detected_at_its_episode_step_and_feature(hub, tmp_path):
    _push(TINY, "alice/tiny-data", episodes=3)
    sha = republish(
        hub.api,
        "alice/tiny-data",
        lambda f: _edit_dataset_value(f, "observation.state", episode=1, frame=7, element=1, delta=0.25),
    )
    report = reproduce("alice/tiny-data", revision=sha, trust_remote_code=True, workers=2, out=tmp_path / "out", progress=False)
    assert not report.reproduced and report.checks["replay"] is False
    replay = report.replay
    assert [e.ok for e in replay.episodes] == [True, False, True]
    (d,) = replay.episodes[1].divergences  # that value only: the env and its states are unchanged
    assert (d.episode, d.seed, d.step, d.feature, d.element) == (1, 1, 7, "observation.state", [1])
    assert d.max_abs_diff == pytest.approx(0.25, abs=1e-6)
    assert d.dataset[1] == pytest.approx(d.replay[1] + 0.25, abs=1e-6)
    # state-restored playback: only the step that produced frame 7 disagrees with the data
    loc = replay.episodes[1].localization
    assert loc["first_step"] == 6 and loc["steps_with_error"] == 1
    assert "playback diverged by 0.25" in loc["message"]
    # the env itself is fine: its benchmark and fingerprint still reproduce
    assert report.checks["benchmark random-policy"] and report.checks["fingerprint"]
    assert any("dataset's files differ" in n for n in report.notes)
    # a declared tolerance above the change accepts it
    loose = reproduce(
        "alice/tiny-data", revision=sha, trust_remote_code=True, tolerance=0.3, write=False, progress=False, benchmarks=False
    )
    assert loose.replay.ok and loose.replay.tolerance == 0.3


# --- env_from_dataset -----------------------------------------------------------------------------


def test_env_from_dataset_rebuilds_the_env_that_recorded_the_data(hub, tmp_path):
    v1 = _push(TINY, "alice/tiny-meta", episodes=2)
    v2 = _push(
        copy_env(tmp_path, edits={"dynamics.py": lambda s: s.replace("GAIN = 1.0", "GAIN = 2.0")}), "alice/tiny-meta", episodes=2
    )
    assert v2.sha != v1.sha and v2.manifest.code_digest != v1.manifest.code_digest

    # the bundled dataset of a snapshot: that snapshot's commit
    pinned = env_from_dataset(f"alice/tiny-meta@{v1.sha}", trust_remote_code=True)
    assert pinned.revision == v1.sha
    snapshot_dataset = pinned.dataset_root
    pinned.unregister()
    from_folder = env_from_dataset(snapshot_dataset, trust_remote_code=True)
    assert from_folder.revision == v1.sha
    from_folder.unregister()

    # a standalone copy: main is v2 (other code); the history search finds v1 by its code digest
    copy = tmp_path / "my-copy"
    shutil.copytree(snapshot_dataset, copy)
    rebuilt = env_from_dataset(copy, trust_remote_code=True)
    assert rebuilt.revision == v1.sha and rebuilt.repo_id == "alice/tiny-meta"
    replayed = replay_dataset(rebuilt.make, copy, rebuilt.config.features_map, progress=False)
    assert replayed.ok
    env = rebuilt.make()
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(obs["agent_pos"], read_episode_frames(copy, 0)["observation.state"][0])
    rebuilt.unregister()

    # a dataset repo of its own (dataset type) holding that copy
    hub.api.create_repo("alice/tiny-meta-data", repo_type="dataset")
    hub.api.upload_folder(repo_id="alice/tiny-meta-data", repo_type="dataset", folder_path=str(copy))
    from_repo = env_from_dataset("alice/tiny-meta-data", trust_remote_code=True)
    assert from_repo.revision == v1.sha
    from_repo.unregister()

    # what cannot be rebuilt says why
    info_path = copy / "meta" / "hub_envs.json"
    info = json.loads(info_path.read_text())
    info["env_meta"]["code_digest"] = "0" * 64
    info_path.write_text(json.dumps(info))
    with pytest.raises(errors.ReproductionError, match="No commit of alice/tiny-meta holds the code"):
        env_from_dataset(copy, trust_remote_code=True)
    with pytest.raises(errors.ReproductionError, match="is not the code that recorded"):
        env_from_dataset(copy, trust_remote_code=True, env_revision=v2.sha)
    del info["env_meta"]
    info_path.write_text(json.dumps(info))
    with pytest.raises(errors.ReproductionError, match="has no hub-envs env_meta"):
        env_from_dataset(copy, trust_remote_code=True)


# --- benchmark details ---------------------------------------------------------------------------


def test_bootstrap_ci_is_seeded_and_brackets_the_mean():
    values = np.random.default_rng(1).normal(3.0, 1.0, size=40)
    lo, hi = bootstrap_ci(values, resamples=1000, seed=0)
    assert lo < values.mean() < hi
    assert (lo, hi) == bootstrap_ci(values, resamples=1000, seed=0)
    assert (lo, hi) != bootstrap_ci(values, resamples=1000, seed=1)
    assert bootstrap_ci([2.0, 2.0, 2.0]) == (2.0, 2.0)


def test_benchmark_policies_hub_envs_cannot_run_are_reported_not_raised(hub):
    pushed = _push(TINY, "alice/tiny-bench")
    loaded = load_env(f"alice/tiny-bench@{pushed.sha}", trust_remote_code=True)
    try:
        base = dict(loaded.manifest.benchmarks[0])
        ok = reproduce_benchmark(loaded, base, progress=False)
        assert ok.passed and [m.name for m in ok.metrics] == ["mean_return", "success_rate"]
        unpinned = reproduce_benchmark(
            loaded, {**base, "policy": {"type": "lerobot", "checkpoint": "alice/policy@main"}}, progress=False
        )
        assert not unpinned.passed and "not pinned to a commit" in unpinned.error
        unknown = reproduce_benchmark(loaded, {**base, "policy": {"type": "scripted"}}, progress=False)
        assert not unknown.passed and "'scripted' is not supported" in unknown.error
        no_tolerance = {**base, "tolerance": {}, "metrics": {"mean_return": base["metrics"]["mean_return"] + 1000.0}}
        far = reproduce_benchmark(loaded, no_tolerance, progress=False)
        assert not far.passed  # without a declared tolerance: the published value must lie in the CI
    finally:
        loaded.unregister()


def _tiny_lerobot_policy(folder: Path) -> Path:
    """A small untrained LeRobot TD-MPC policy for the tiny env (state (2,) -> action (1,)), saved as LeRobot saves one."""
    import torch
    from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    from lerobot.policies.tdmpc.configuration_tdmpc import TDMPCConfig

    cfg = TDMPCConfig(
        input_features={"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(2,))},
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(1,))},
        device="cpu",
        latent_dim=8,
        mlp_dim=16,
        q_ensemble_size=2,
        horizon=2,
        cem_iterations=2,
        n_gaussian_samples=16,
        n_pi_samples=4,
        n_elites=4,
        normalization_mapping={
            "STATE": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.MIN_MAX,
            "VISUAL": NormalizationMode.IDENTITY,
        },
    )
    torch.manual_seed(0)
    get_policy_class("tdmpc")(cfg).save_pretrained(folder)
    pre, post = make_pre_post_processors(cfg, dataset_stats={"action": {"min": torch.tensor([-1.0]), "max": torch.tensor([1.0])}})
    pre.save_pretrained(folder)
    post.save_pretrained(folder)
    return folder


def test_a_declared_lerobot_policy_checkpoint_benchmark_is_reproduced(hub, tmp_path):
    policy_sha = hub.api.upload_folder(
        repo_id=hub.api.create_repo("alice/tiny-policy").repo_id, folder_path=str(_tiny_lerobot_policy(tmp_path / "policy"))
    ).oid
    pushed = _push(TINY, "alice/tiny-policy-env", episodes=3)
    spec = {
        "name": "tdmpc-untrained",
        "policy": {"type": "lerobot", "checkpoint": f"alice/tiny-policy@{policy_sha}"},
        "episodes": 3,
        "seeds": [100, 101, 102],
        "metrics": {"mean_return": 0.0, "success_rate": 0.0},
        "tolerance": {"mean_return": 1e-9, "success_rate": 0.0},
    }
    # the publisher evaluates the policy once and declares the result in the manifest
    loaded = load_env(f"alice/tiny-policy-env@{pushed.sha}", trust_remote_code=True)
    evaluated = reproduce_benchmark(loaded, spec, workers=1, progress=False, trust_policy_code=True)
    loaded.unregister()
    assert evaluated.error is None
    returns = evaluated.reproduced_per_episode["return"]
    spec["metrics"] = {
        "mean_return": float(np.mean(returns)),
        "success_rate": float(np.mean(evaluated.reproduced_per_episode["success"])),
    }
    spec["per_episode"] = {"return": returns, "success": evaluated.reproduced_per_episode["success"]}

    def declare(folder: Path) -> None:
        manifest = json.loads((folder / "hub_env.json").read_text())
        manifest["benchmarks"].append(spec)
        (folder / "hub_env.json").write_text(json.dumps(manifest))

    declared = republish(hub.api, "alice/tiny-policy-env", declare)
    # consent to the env does not cover the policy: another repo, whose loading can import code
    report = reproduce(
        "alice/tiny-policy-env", revision=declared, trust_remote_code=True, workers=1, write=False, progress=False, replay=False
    )
    assert (
        not report.reproduced and f"benchmark policy alice/tiny-policy@{policy_sha} is another repo" in report.benchmarks[1].error
    )
    trust("alice/tiny-policy", policy_sha)  # its own consent, bound to the files of that commit
    report = reproduce("alice/tiny-policy-env", revision=declared, trust_remote_code=True, workers=2, write=False, progress=False)
    assert report.reproduced, report.summary()
    assert [b.name for b in report.benchmarks] == ["random-policy", "tdmpc-untrained"]
    assert report.benchmarks[1].reproduced_per_episode["return"] == returns  # bit-identical, on 2 workers

    perturbed = republish(hub.api, "alice/tiny-policy-env", _perturb_gain)
    report = reproduce(
        "alice/tiny-policy-env", revision=perturbed, trust_remote_code=True, workers=1, write=False, progress=False, replay=False
    )
    checkpoint = report.benchmarks[1]
    assert not checkpoint.passed and checkpoint.error is None and checkpoint.episodes_differing


def test_a_policy_checkpoint_importing_code_never_loads_without_its_own_consent(hub, tmp_path, monkeypatch):
    """The red-team's attack: a benchmark names a policy whose processor config makes LeRobot's factory import
    and call ``subprocess.Popen``. Consent to the env (trust_remote_code) does not reach it."""
    marker = tmp_path / "popen-ran"
    folder = _tiny_lerobot_policy(tmp_path / "policy")
    config = json.loads((folder / "policy_preprocessor.json").read_text())
    config["steps"].insert(0, {"class": "subprocess.Popen", "config": {"args": ["touch", str(marker)]}})
    (folder / "policy_preprocessor.json").write_text(json.dumps(config))
    policy_sha = hub.api.upload_folder(repo_id=hub.api.create_repo("mallory/policy").repo_id, folder_path=str(folder)).oid
    pushed = _push(TINY, "mallory/policy-env", episodes=2)

    def declare(f: Path) -> None:
        manifest = json.loads((f / "hub_env.json").read_text())
        manifest["benchmarks"].append(
            {
                "name": "evil",
                "policy": {"type": "lerobot", "checkpoint": f"mallory/policy@{policy_sha}"},
                "episodes": 2,
                "seeds": [1, 2],
                "metrics": {"mean_return": 0.0},
            }
        )
        (f / "hub_env.json").write_text(json.dumps(manifest))

    sha = republish(hub.api, "mallory/policy-env", declare)
    report = reproduce(
        "mallory/policy-env", revision=sha, trust_remote_code=True, workers=1, write=False, progress=False, replay=False
    )
    error = report.benchmarks[-1].error
    assert "subprocess.Popen" in error and f"hub-envs trust mallory/policy@{policy_sha}" in error
    assert not marker.exists()
    assert pushed.sha != sha


_ENDS = (
    "return self._obs(), reward, False, False, self._info()",
    "return self._obs(), reward, bool(abs(self.pos[0]) > 0.5), False, self._info()",
)


def test_an_episode_end_that_moved_is_named_in_both_directions(hub, tmp_path):
    assert _ENDS[0] in (TINY / "tiny.py").read_text()
    original = (TINY / "tiny.py").read_text()

    # data recorded by code that ends episodes (|pos| > 0.5); a later commit no longer ends them
    _push(copy_env(tmp_path, edits={"tiny.py": lambda s: s.replace(*_ENDS)}), "alice/tiny-ends", episodes=6)
    sha = republish(hub.api, "alice/tiny-ends", lambda f: (f / "tiny.py").write_text(original))
    report = reproduce(
        "alice/tiny-ends", revision=sha, trust_remote_code=True, workers=1, write=False, progress=False, benchmarks=False
    )
    ended = [e for e in report.replay.episodes if e.length < 30]
    assert ended, "some episode should have ended early"
    for e in ended:
        done = next(d for d in e.divergences if d.feature == "next.done")
        assert (done.step, done.dataset, done.replay) == (e.length - 1, True, False)
        assert "the env did not end it there" in done.note
    assert all(e.ok for e in report.replay.episodes if e.length == 30)

    # data recorded by code that never ends episodes; a later commit ends them
    _push(TINY, "alice/tiny-ends-later", episodes=6)
    sha = republish(hub.api, "alice/tiny-ends-later", lambda f: (f / "tiny.py").write_text(original.replace(*_ENDS)))
    report = reproduce(
        "alice/tiny-ends-later", revision=sha, trust_remote_code=True, workers=1, write=False, progress=False, benchmarks=False
    )
    dataset = report_dataset(report)
    for e in report.replay.episodes:
        rewards = read_episode_frames(dataset, e.episode)["next.reward"][:, 0]
        expected = np.flatnonzero(-rewards.astype(np.float64) > 0.5)  # |pos| after each action, from the data
        if not len(expected):
            assert e.ok
            continue
        done = next(d for d in e.divergences if d.feature == "next.done")
        assert (done.step, done.dataset, done.replay) == (int(expected[0]), False, True)
        assert f"the env ended the episode after step {int(expected[0])}" in done.note


def test_without_recorded_states_the_replay_state_localizes_the_divergence(hub):
    _push(TINY, "alice/tiny-nostates")

    def old_style_and_perturbed(folder: Path) -> None:
        (folder / "dataset" / "meta" / "env_states.parquet").unlink()  # as datasets without recorded states
        _perturb_gain(folder)

    sha = republish(hub.api, "alice/tiny-nostates", old_style_and_perturbed)
    report = reproduce(
        "alice/tiny-nostates", revision=sha, trust_remote_code=True, workers=1, write=False, progress=False, benchmarks=False
    )
    replay = report.replay
    assert "env_state" not in replay.features and replay.states.startswith("not recorded")
    first = replay.first_divergence
    assert (first.episode, first.step, first.feature) == (0, 0, "next.reward")
    loc = replay.episodes[0].localization
    assert loc["method"].startswith("replay state") and loc["first_step"] == 0
    assert "reproduces the diverging step" in loc["message"]


def test_the_fingerprint_comes_from_random_episodes_that_ran_already():
    """reproduce takes the golden-rollout fingerprint from the benchmark's random-policy episodes (longer, or ended
    by the env before the fingerprint's steps) instead of running its seeds again: the same digests."""
    import gymnasium as gym

    from hub_envs.harness.checks import golden_fingerprint, verify_fingerprint
    from hub_envs.harness.rollout import run_episodes

    def unused():
        raise AssertionError("the fingerprint ran the env again")

    for env_id in ("Pendulum-v1", "CartPole-v1"):  # CartPole's random episodes end before 32 steps (seed 0: 13)
        make = lambda env_id=env_id: gym.make(env_id)  # noqa: E731
        recorded = golden_fingerprint(make, seeds=[0, 1, 2], steps=32)
        ran = run_episodes(make, [0, 1, 2], max_steps=100, progress=False)
        assert verify_fingerprint(unused, recorded, where="x", episodes=ran) == recorded
        other = {**recorded, "digest": "0" * 64}
        with pytest.raises(errors.FingerprintMismatchError):
            verify_fingerprint(unused, other, where="x", episodes=ran)
    # rollouts of other seeds are not taken for them
    assert verify_fingerprint(make, recorded, where="x", episodes=ran[::-1]) == recorded


def test_the_engine_runs_replayed_and_random_episodes_in_one_pass():
    """What reproduce relies on to share one worker pool: per-episode None = the seeded random policy."""
    import gymnasium as gym

    from hub_envs.harness.rollout import run_episodes

    make = lambda: gym.make("Pendulum-v1")  # noqa: E731
    random = run_episodes(make, [0, 1, 2], max_steps=40, progress=False)
    mixed = run_episodes(make, [0, 1, 2], max_steps=40, policy=[None, random[1].actions, None], progress=False)
    assert mixed == random
    assert run_episodes(make, [0, 1, 2], max_steps=40, policy=[None, random[1].actions, None], workers=2, progress=False) == mixed
    with pytest.raises(errors.ConfigError, match="mixes None"):
        run_episodes(make, [0, 1], max_steps=40, policy=[None, random[1].actions[0]], progress=False)
