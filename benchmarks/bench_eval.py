"""Policy evaluation: ``hub-envs evaluate`` against LeRobot's own ``lerobot-eval``, the same policy, env and seeds.

The pendulum example env is pushed to a loopback Hub; a tiny LeRobot checkpoint is made here: a TD-MPC policy
(state in, action out; ``use_mpc=False``, so ``select_action`` is its policy network alone and deterministic),
randomly initialised from a fixed torch seed and saved with ``save_pretrained`` beside its pre/post-processors,
then uploaded to the loopback Hub as a model repo. The commands run as fresh processes, as a user runs them,
``repeats`` times in turn (each goes first in turn):

* ``hub-envs evaluate --repo_id=bench/pendulum@<sha> --policy=bench/tiny-tdmpc@<sha> --episodes=N --seed=1000``
  (its defaults: up to 2 worker processes);
* ``lerobot-eval --env.discover_packages_path=hub_envs.lerobot_plugin --env.type=hub --env.repo_id=bench/pendulum
  --env.revision=<sha> --policy.path=<the same checkpoint folder> --eval.n_episodes=N --seed=1000``, with
  ``--eval.batch_size=1`` and with ``--eval.batch_size=10`` (LeRobot's loop: it resets episode ``i`` with seed
  ``1000 + i``, as hub-envs does; batch 1 runs the very same episodes, batch 10 runs the policy on a batch, whose
  float arithmetic differs slightly. It also renders and writes videos of the first 10 episodes, which it always
  does and no flag turns off).

Figures (medians of the per-repeat ratios):

* ``eval_vs_lerobot_eval``: episodes/s of ``hub-envs evaluate`` ÷ those of ``lerobot-eval`` at batch 1, the setting
  that runs the same episodes (wall time of each command, start-up included: what the user waits for). Goal >= 1.5.
* ``eval_vs_lerobot_eval_batch10`` (info): the same ÷ ``lerobot-eval`` at batch 10, LeRobot's batched inference: one
  forward pass of the policy for 10 envs, which for a tiny policy is cheaper than 10 single ones; hub-envs keeps one
  episode per forward pass so that its results do not depend on the number of workers.
* ``eval_success_rate_difference``: the largest difference of the three success rates on the same seeds. Goal == 0.
* ``eval_return_max_abs_difference``: the largest per-episode return difference between hub-envs and ``lerobot-eval``
  at batch 1 (``eval.json`` vs LeRobot's ``eval_info.json``): the same episodes give the same returns up to float
  summation order.

Run: ``python -m benchmarks.bench_eval [--repeats 3] [--episodes 100]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
ENV = "pendulum"
SEED = 1000


def tiny_policy(folder: Path, state_dim: int, action_dim: int) -> Path:
    """A randomly initialised, deterministic TD-MPC checkpoint (state -> action), saved as LeRobot saves one."""
    import torch
    from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    from lerobot.policies.tdmpc.configuration_tdmpc import TDMPCConfig

    cfg = TDMPCConfig(
        input_features={"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(state_dim,))},
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))},
        device="cpu",
        latent_dim=16,
        mlp_dim=32,
        q_ensemble_size=2,
        use_mpc=False,  # the policy network alone: no sampling, the same action for the same observation
        n_action_repeats=1,
        normalization_mapping={
            "STATE": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.MIN_MAX,
            "VISUAL": NormalizationMode.IDENTITY,
        },
    )
    torch.manual_seed(0)
    get_policy_class("tdmpc")(cfg).save_pretrained(folder)
    stats = {"action": {"min": -torch.ones(action_dim), "max": torch.ones(action_dim)}}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    pre.save_pretrained(folder)
    post.save_pretrained(folder)
    return folder


def _run(cmd: list[str], env: dict) -> tuple[float, subprocess.CompletedProcess]:
    t = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:3])} failed ({done.returncode}):\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")
    return seconds, done


def _hub_envs(env: dict, repo: str, policy: str, episodes: int) -> tuple[float, dict]:
    cmd = [
        str(BIN / "hub-envs"),
        "evaluate",
        f"--repo_id={repo}",
        "--trust_remote_code=true",
        f"--policy={policy}",
        "--trust_policy_code=true",
        f"--episodes={episodes}",
        f"--seed={SEED}",
        "--json=true",
    ]
    seconds, done = _run(cmd, env)
    result = json.loads(done.stdout[done.stdout.index("{") :])
    return seconds, {"returns": result["returns"], "successes": result["successes"], "workers": result["backend"]}


def _lerobot_eval(env: dict, name: str, sha: str, policy_dir: Path, episodes: int, out: Path, batch: int) -> tuple[float, dict]:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [
        str(BIN / "lerobot-eval"),
        "--env.discover_packages_path=hub_envs.lerobot_plugin",
        "--env.type=hub",
        f"--env.repo_id={name}",
        f"--env.revision={sha}",
        "--env.trust_remote_code=true",
        f"--policy.path={policy_dir}",
        "--policy.device=cpu",
        f"--eval.n_episodes={episodes}",
        f"--eval.batch_size={batch}",
        f"--seed={SEED}",
        f"--output_dir={out}",
    ]
    seconds, _ = _run(cmd, env)
    info = json.loads((out / "eval_info.json").read_text())
    metrics = info["per_task"][0]["metrics"]
    return seconds, {"returns": metrics["sum_rewards"], "successes": metrics["successes"]}


def run(repeats: int = 3, episodes: int = 100, verbose: bool = True) -> dict:
    """Push the env and the policy to a loopback Hub, then time both evaluations; return the figures."""
    from huggingface_hub import HfApi

    from hub_envs import load_env, push_env
    from hub_envs.testing import HubServer, hub_environment

    results: dict = {
        "cpu_count": os.cpu_count(),
        "repeats": repeats,
        "episodes": episodes,
        "load_average_before": os.getloadavg(),
    }
    tmp = Path(tempfile.mkdtemp(prefix="bench-eval-"))
    try:
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            sha = push_env(REPO / "envs" / ENV, f"bench/{ENV}", episodes=2, progress=False).sha
            with load_env(f"bench/{ENV}@{sha}", trust_remote_code=True) as loaded:
                features = loaded.config.features
                state_dim, action_dim = features["agent_pos"].shape[0], features["action"].shape[0]
            policy_dir = tiny_policy(tmp / "tiny-tdmpc", state_dim, action_dim)
            api = HfApi()
            api.create_repo("bench/tiny-tdmpc")
            policy = f"bench/tiny-tdmpc@{api.upload_folder(repo_id='bench/tiny-tdmpc', folder_path=str(policy_dir)).oid}"
            env = {**os.environ, "HF_HUB_DISABLE_PROGRESS_BARS": "1", "TQDM_DISABLE": "1"}
            repo = f"bench/{ENV}@{sha}"
            runs = {"hub_envs": None, "lerobot_eval_batch1": 1, "lerobot_eval_batch10": 10}
            times: dict[str, list[float]] = {who: [] for who in runs}
            ratios, outcomes = [], {}
            for i in range(repeats):
                names = list(runs)
                for who in names[i % len(names) :] + names[: i % len(names)]:  # each goes first in turn
                    if runs[who] is None:
                        seconds, outcome = _hub_envs(env, repo, policy, episodes)
                    else:
                        seconds, outcome = _lerobot_eval(env, f"bench/{ENV}", sha, policy_dir, episodes, tmp / "out", runs[who])
                    times[who].append(seconds)
                    outcomes[who] = outcome
                ratios.append(times["lerobot_eval_batch1"][-1] / times["hub_envs"][-1])  # the same episodes
            hub = outcomes["hub_envs"]
            for who, outcome in outcomes.items():
                results[who] = {
                    "seconds": [round(t, 2) for t in times[who]],
                    "episodes_per_s": round(episodes / statistics.median(times[who]), 3),
                    "success_rate": sum(outcome["successes"]) / len(outcome["successes"]),
                    "same_successes": outcome["successes"] == hub["successes"],
                    "return_max_abs_difference": max(abs(a - b) for a, b in zip(hub["returns"], outcome["returns"])),
                }
            results["hub_envs"]["backend"] = hub["workers"]
            results["eval_vs_lerobot_eval_each"] = [round(r, 3) for r in ratios]
            results["eval_vs_lerobot_eval"] = round(statistics.median(ratios), 3)
            for batch in (1, 10):
                results[f"eval_vs_lerobot_eval_batch{batch}"] = round(
                    statistics.median(a / b for a, b in zip(times[f"lerobot_eval_batch{batch}"], times["hub_envs"])), 3
                )
            rates = [results[who]["success_rate"] for who in runs]
            results["eval_success_rate_difference"] = max(rates) - min(rates)
            results["eval_return_max_abs_difference"] = results["lerobot_eval_batch1"]["return_max_abs_difference"]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    results["load_average_after"] = os.getloadavg()
    if verbose:
        print_table(results)
    return results


def print_table(results: dict) -> None:
    print(f"\nPolicy evaluation, {results['episodes']} episodes of {ENV}, tiny TD-MPC checkpoint ({results['cpu_count']} CPUs)")
    for who, label in (
        ("hub_envs", f"hub-envs evaluate ({results['hub_envs']['backend']})"),
        ("lerobot_eval_batch1", "lerobot-eval --eval.batch_size=1"),
        ("lerobot_eval_batch10", "lerobot-eval --eval.batch_size=10"),
    ):
        r = results[who]
        print(
            f"{label:45} {r['seconds']} s, {r['episodes_per_s']} episodes/s, success rate {r['success_rate']}, "
            f"same successes as hub-envs: {r['same_successes']}, largest return difference {r['return_max_abs_difference']:.3g}"
        )
    print(
        f"eval_vs_lerobot_eval = {results['eval_vs_lerobot_eval']:.2f} (goal >= 1.5; against batch 1, the same episodes; each "
        f"repeat: {', '.join(f'{r:.2f}' for r in results['eval_vs_lerobot_eval_each'])}); against batch 10: "
        f"{results['eval_vs_lerobot_eval_batch10']:.2f} (info); "
        f"success rate difference {results['eval_success_rate_difference']}; load average before: {results['load_average_before'][0]:.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    run(repeats=args.repeats, episodes=args.episodes)


if __name__ == "__main__":
    main()
