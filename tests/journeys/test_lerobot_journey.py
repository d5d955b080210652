"""Journey: a LeRobot user on an env someone pushed, with LeRobot's own tools and the env's repo id alone.

push_env (the author, with a token) → ``LeRobotDataset(repo_id)`` → ``lerobot-train --dataset.repo_id`` (a few
steps of a tiny ACT) → ``lerobot-eval`` on the hub env with that checkpoint → ``hub-envs compare`` against the
random policy. LeRobot's CLIs run as subprocesses, exactly as a user types them, in a fresh cache without a token.
The env is reach (pybullet, a 96x96 camera stored as video), its episodes cut to 10 steps.

The flags that differ by LeRobot version are LeRobot's own: ``--eval_freq`` (0.4) / ``--env_eval_freq`` (0.5+), and
``--dataset.video_backend=pyav`` where LeRobot's default backend cannot decode here (0.4 picks an installed torchcodec
that cannot load its FFmpeg libraries; 0.5+ falls back to pyav itself); LeRobot 0.4 finds the ``hub`` plugin
through ``--env.discover_packages_path`` (0.5+ imports the installed ``lerobot_env_hub`` distribution itself).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

from helpers import copy_env

from hub_envs import _compat, push_env
from hub_envs.cli import main as cli_main
from hub_envs.testing import hub_environment

ROOT = Path(__file__).resolve().parents[2]
REPO = "alice/reach"

#: A tiny ACT: seconds on a CPU.
TINY_ACT = [
    "--policy.type=act",
    "--policy.push_to_hub=false",
    "--policy.device=cpu",
    "--policy.dim_model=32",
    "--policy.n_heads=2",
    "--policy.dim_feedforward=64",
    "--policy.n_encoder_layers=1",
    "--policy.n_decoder_layers=1",
    "--policy.chunk_size=5",
    "--policy.n_action_steps=5",
    "--policy.use_vae=false",
    "--policy.pretrained_backbone_weights=null",
]


def _lerobot(command: str, *flags: str, cwd: Path) -> subprocess.CompletedProcess:
    """One of LeRobot's console scripts of this venv, in a fresh process with the caller's environment."""
    run = subprocess.run(
        [str(Path(sys.executable).with_name(command)), *flags], capture_output=True, text=True, timeout=900, cwd=cwd
    )
    assert run.returncode == 0, f"{command} failed:\n{run.stdout[-3000:]}\n{run.stderr[-6000:]}"
    return run


def test_a_lerobot_user_trains_and_evaluates_on_a_pushed_env_by_its_repo_id(hub_with_token, tmp_path):
    hub, times, t = hub_with_token, {}, time.perf_counter()

    # the author publishes (HF_TOKEN set by the fixture): the env repo, and its dataset as the dataset repo
    folder = copy_env(
        tmp_path,
        ROOT / "envs" / "reach",
        "reach",
        {"config.py": lambda s: s.replace("episode_length: int = 100", "episode_length: int = 10")},
    )
    pushed = push_env(folder, REPO, episodes=2, progress=False)
    manifest = pushed.manifest
    times["push"], t = time.perf_counter() - t, time.perf_counter()

    # what a LeRobot user adds to a command on this stack (nothing on LeRobot >= 0.5)
    video = [] if _compat.lerobot_default_video_backend() == _compat.video_backend() else ["--dataset.video_backend=pyav"]
    plugin = [] if _compat.env_configs_create_envs() else ["--env.discover_packages_path=hub_envs.lerobot_plugin"]
    with hub_environment(hub.endpoint, tmp_path / "lerobot-user"):  # another machine: nothing cached, no token
        # 1. LeRobot's dataset class, by repo id: the bytes the env's manifest hashes, at the published revision
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        ds = LeRobotDataset(REPO, **({"video_backend": "pyav"} if video else {}))
        assert (
            ds.num_episodes == 2 and ds.num_frames == manifest.dataset["frames"] and ds.meta.video_keys == ["observation.image"]
        )
        files = {
            p.relative_to(ds.root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for top in ("meta", "data", "videos")
            for p in (Path(ds.root) / top).rglob("*")
            if p.is_file()
        }
        assert files == {p.removeprefix("dataset/"): h for p, h in manifest.files.items() if p.startswith("dataset/")}
        assert tuple(ds[0]["observation.image"].shape) == (3, 96, 96)
        times["LeRobotDataset"], t = time.perf_counter() - t, time.perf_counter()

        # 2. lerobot-train on it, by repo id: no --dataset.root, no hub-envs wrapper
        train = tmp_path / "train"
        _lerobot(
            "lerobot-train",
            f"--dataset.repo_id={REPO}",
            *video,
            *TINY_ACT,
            "--batch_size=2",
            "--num_workers=0",
            "--steps=2",
            "--save_freq=2",
            "--log_freq=1",
            f"--{_compat.train_eval_freq_flag()}=0",
            f"--output_dir={train}",
            cwd=tmp_path,
        )
        checkpoint = train / "checkpoints" / "last" / "pretrained_model"
        saved = json.loads((checkpoint / "train_config.json").read_text())
        assert saved["dataset"]["repo_id"] == REPO and saved["dataset"]["root"] is None and saved["steps"] == 2
        times["lerobot-train"], t = time.perf_counter() - t, time.perf_counter()

        # 3. lerobot-eval on the hub env, by its per-repo choice, with the one consent flag (--env.trust_remote_code)
        evaluation = tmp_path / "eval"
        _lerobot(
            "lerobot-eval",
            *plugin,
            f"--env.type={REPO}@{pushed.sha[:12]}",
            "--env.trust_remote_code=true",
            f"--policy.path={checkpoint}",
            "--policy.device=cpu",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            f"--output_dir={evaluation}",
            cwd=tmp_path,
        )
        info = json.loads((evaluation / "eval_info.json").read_text())
        assert info["overall"]["n_episodes"] == 2 and "reach" in info["per_group"]
        times["lerobot-eval"], t = time.perf_counter() - t, time.perf_counter()

        # 4. the checkpoint against the random policy, on the same seeds of the same commit
        out = tmp_path / "compare"
        argv = [f"--repo_id={REPO}@{pushed.sha}", f"--policies={checkpoint},random", "--episodes=2", "--trust_remote_code=true"]
        assert cli_main(["compare", *argv, f"--out={out}"]) == 0
        report = json.loads((out / "report.json").read_text())
        assert len(report["policies"]) == 2 and report["policies"][1]["label"] == "random"
        assert all(len(p["returns"]["values"]) == 2 for p in report["policies"]) and len(report["differences"]) == 1
        assert report["provenance"]["sha"] == pushed.sha
        times["compare"] = time.perf_counter() - t
    print("journey timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in times.items()))
