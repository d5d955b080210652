"""``make train-long``: publish envs to the embedded Hub, train LeRobot's ACT on their random-action
datasets with ``hub-envs train``, evaluate with ``hub-envs eval``, and print what it took.

The CI test (tests/test_lerobot.py) trains for 3 steps; this runs the same commands long enough to
see the loss fall and the policy act (still CPU-sized: a small ACT, a few thousand frames).

    python -m benchmarks.train_long [--envs reach pendulum] [--episodes 20] [--steps 1000] [--eval-episodes 10]

``pendulum`` is published observing pixels too (``obs_type="pixels_agent_pos"``): LeRobot's ACT and
diffusion policies need an image or an ``environment_state`` input, and pendulum's default is state only.
Results (eval_info.json with provenance, checkpoints) go to ``benchmarks/out/train_long/<env>/``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

from hub_envs._compat import train_eval_freq_flag

ROOT = Path(__file__).resolve().parent.parent
ACT = [
    "--policy.type=act",
    "--policy.push_to_hub=false",
    "--policy.device=cpu",
    "--policy.dim_model=128",
    "--policy.n_heads=4",
    "--policy.dim_feedforward=512",
    "--policy.n_encoder_layers=2",
    "--policy.n_decoder_layers=1",
    "--policy.chunk_size=20",
    "--policy.n_action_steps=10",
    "--policy.use_vae=false",
    "--policy.pretrained_backbone_weights=null",
]


def _env_folder(name: str, tmp: Path) -> Path:
    src = ROOT / "envs" / name
    if name != "pendulum":
        return src
    dest = tmp / "pendulum"
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("__pycache__"))
    config = dest / "config.py"
    config.write_text(config.read_text().replace('obs_type: str = "state"', 'obs_type: str = "pixels_agent_pos"'))
    return dest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["reach", "pendulum"])
    parser.add_argument("--episodes", type=int, default=20, help="episodes in each published dataset")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out" / "train_long")
    args = parser.parse_args(argv)

    from hub_envs import load_env, push_env
    from hub_envs.cli import main as hub_envs
    from hub_envs.testing import HubServer, hub_environment

    rows = []
    with tempfile.TemporaryDirectory(prefix="hub-envs-train-long-") as tmp_name:
        tmp = Path(tmp_name)
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "hf_home"):
            for name in args.envs:
                out = args.out / name
                shutil.rmtree(out, ignore_errors=True)
                t0 = time.perf_counter()
                sha = push_env(_env_folder(name, tmp), f"bench/{name}", episodes=args.episodes, seed=0).sha
                t1 = time.perf_counter()
                env = ["--env.type=hub", f"--env.repo_id=bench/{name}", f"--env.revision={sha}", "--env.trust_remote_code=true"]
                rc = hub_envs(
                    [
                        "train",
                        *env,
                        *ACT,
                        f"--steps={args.steps}",
                        f"--batch_size={args.batch_size}",
                        "--num_workers=2",
                        f"--{train_eval_freq_flag()}=0",
                        f"--save_freq={args.steps}",
                        f"--log_freq={max(1, args.steps // 20)}",
                        f"--output_dir={out / 'train'}",
                    ]
                )
                t2 = time.perf_counter()
                batch = min(args.eval_episodes, 5)
                rc = rc or hub_envs(
                    [
                        "eval",
                        *env,
                        f"--policy.path={out / 'train' / 'checkpoints' / 'last' / 'pretrained_model'}",
                        "--policy.device=cpu",
                        f"--eval.n_episodes={args.eval_episodes}",
                        f"--eval.batch_size={batch}",
                        f"--output_dir={out / 'eval'}",
                    ]
                )
                t3 = time.perf_counter()
                if rc:
                    print(f"{name}: failed with exit code {rc}")
                    return rc
                info = json.loads((out / "eval" / "eval_info.json").read_text())
                random_policy = load_env(f"bench/{name}@{sha}", trust_remote_code=True).manifest.benchmarks[0]["metrics"]
                rows.append(
                    (
                        name,
                        sha[:12],
                        t1 - t0,
                        t2 - t1,
                        t3 - t2,
                        info["overall"]["avg_sum_reward"],
                        info["overall"]["pc_success"],
                        random_policy["mean_return"],
                        info["provenance"]["env"]["dataset_fingerprint"][:12],
                    )
                )

    print(
        f"\n{'env':10} {'sha':12} {'push s':>7} {'train s':>8} {'eval s':>7} {'return':>9} {'success %':>9} "
        f"{'random return':>13}  dataset"
    )
    for name, sha, push_s, train_s, eval_s, ret, success, random_ret, fp in rows:
        print(f"{name:10} {sha:12} {push_s:7.1f} {train_s:8.1f} {eval_s:7.1f} {ret:9.2f} {success:9.1f} {random_ret:13.2f}  {fp}")
    print(f"\nResults with provenance: {args.out}/<env>/eval/eval_info.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
