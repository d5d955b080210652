"""What the embedded Hub's web pages cost the server, side by side with an API request.

A real ``hub-envs serve`` subprocess holds ``envs/pendulum`` published with push_env; then, on
keep-alive HTTP connections (``requests.Session``):

* ``repo_page_rps``: ``GET /{user}/{repo}`` (card rendered and cached, file list, commits, refs).
* ``home_page_rps``: ``GET /`` as a browser asks for it (every repo: title, tags, last commit).
* ``blob_page_rps``: ``GET /{user}/{repo}/blob/main/pendulum_env.py`` (highlighted once, then from a cache).
* ``api_info_rps``: ``GET /api/models/{user}/{repo}``, the request ``HfApi.model_info`` sends.
* ``repo_page_vs_api``: ``repo_page_rps`` ÷ ``api_info_rps``.
* ``repo_page_rps_4_clients``: the repo page with 4 clients at once (the server is one process).
* ``repo_page_first_ms``: the first repo page (the card rendered from Markdown, not cached).

The dataset viewer and the pull request pages, on a dataset repo of 1000 small episodes (20 steps each, in the
LeRobot v3 layout hub-envs writes) and on the env's repo with an attestation pull request:

* ``api_info_first_ms``, ``episodes_first_ms``, ``episode_first_ms``: on a fresh server, in this order, the first
  ``GET /api/datasets/{repo}``, the first episodes list (pyarrow imported, the episodes index read), and the first
  episode page with its data (what a browser fetches: the page, then ``data.json``).
* ``episodes_page_rps``: ``GET .../episodes`` (the index cached); ``episode_data_rps``: ``GET .../episodes/{i}/data.json``
  for episodes drawn at random among the 1000 (mostly not cached: each reads its rows from the parquet file);
  ``episode_page_rps``: ``GET .../episodes/{i}``; ``pr_page_rps``: ``GET .../discussions/1`` (the diff, the record);
  ``repo_page_matrix_rps``: the env's page with its reproductions matrix. Each interleaved with ``api_info_rps``.
* ``*_vs_api``: each of those ÷ ``viewer_api_info_rps`` (``GET /api/models/{repo}``, interleaved with them).
* ``viewer_rss_mb``: the server's resident memory after the data of every one of the 1000 episodes was fetched
  (the caches are bounded).

Requests per second of one client, sequential, the requests of the four URLs interleaved one by one
(so that each sees the same load on a shared machine): the median over ``rounds`` rounds of
``requests`` requests to each URL. Run: ``python -m benchmarks.bench_pages [--rounds 5] [--requests 100]``.
"""

from __future__ import annotations

import argparse
import json
import random
import shutil
import statistics
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import requests
from huggingface_hub import CommitOperationAdd, HfApi

from hub_envs.testing import HubServer, hub_environment

REPO_ROOT = Path(__file__).resolve().parent.parent
HTML = {"Accept": "text/html,application/xhtml+xml,*/*;q=0.8"}


def _get(session: requests.Session, url: str, headers: dict | None) -> float:
    """One request's seconds (the whole body read)."""
    start = time.perf_counter()
    r = session.get(url, headers=headers, timeout=60)
    if r.status_code != 200:
        raise RuntimeError(f"GET {url}: {r.status_code} {r.text[:200]}")
    return time.perf_counter() - start


def _interleaved_rates(session: requests.Session, urls: dict, n: int) -> dict[str, float]:
    """Requests/s of each url, its requests interleaved one by one with the others' (page, API, page,
    API...): on a shared machine, each sees the same load."""
    seconds = dict.fromkeys(urls, 0.0)
    for _ in range(n):
        for key, (url, headers) in urls.items():
            seconds[key] += _get(session, url, headers)
    return {key: n / total for key, total in seconds.items()}


def _concurrent_rate(url: str, clients: int, n: int) -> float:
    def worker() -> None:
        with requests.Session() as s:
            for _ in range(n):
                s.get(url, timeout=60).raise_for_status()

    threads = [threading.Thread(target=worker) for _ in range(clients)]
    start = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return clients * n / (time.perf_counter() - start)


def _many_episodes(root: Path, n: int = 1000, steps: int = 20) -> None:
    from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset

    features = {
        "observation.state": {"dtype": "float32", "shape": [6], "names": None},
        "action": {"dtype": "float32", "shape": [2], "names": None},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "next.done": {"dtype": "bool", "shape": [1], "names": None},
        "next.success": {"dtype": "bool", "shape": [1], "names": None},
    }
    rng = np.random.default_rng(0)
    last = (np.arange(steps) == steps - 1).reshape(steps, 1)
    episodes = (
        EpisodeFrames(i, seed=i, frames={"observation.state": rng.normal(size=(steps, 6)).astype(np.float32),
                                         "action": rng.uniform(-1, 1, (steps, 2)).astype(np.float32),
                                         "next.reward": rng.normal(size=(steps, 1)).astype(np.float32),
                                         "next.done": last, "next.success": last & (i % 3 == 0)})
        for i in range(n)
    )  # fmt: skip
    write_lerobot_dataset(root, repo_id="bench/many", fps=20, features=features, episodes=episodes, task="bench", progress=False)


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _first_ms(session: requests.Session, *urls: str) -> float:
    start = time.perf_counter()
    for url in urls:
        session.get(url, timeout=120).raise_for_status()
    return 1000 * (time.perf_counter() - start)


def run_viewer(rounds: int = 5, requests_per_round: int = 100) -> dict:
    """The dataset viewer and the pull request pages (see the module docstring)."""
    from hub_envs import push_env

    tmp = Path(tempfile.mkdtemp(prefix="bench-viewer-"))
    try:
        _many_episodes(tmp / "many")
        results: dict[str, float] = {}
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            api, base = HfApi(), server.endpoint
            api.create_repo("bench/many", repo_type="dataset")
            sha = api.upload_folder(repo_id="bench/many", repo_type="dataset", folder_path=str(tmp / "many")).oid
            env_id = "bench/pendulum-lerobot"
            pushed = push_env(REPO_ROOT / "envs" / "pendulum", env_id, episodes=2, progress=False)
            record = {"kind": "hub-envs reproduction attestation", "format_version": 1, "sha": pushed.sha,
                      "verdict": "REPRODUCED", "reproduced": True, "stack_digest": "0123456789ab",
                      "stack": {"python": "3.13", "packages": {}}, "created_at": "2026-01-01T00:00:00Z"}  # fmt: skip
            path = "reproductions/2026-01-01-0123456789ab.json"
            api.create_commit(
                env_id, [CommitOperationAdd(path, json.dumps(record, indent=2).encode())], commit_message="attest", create_pr=True
            )
        # a fresh server on the same store: cold caches, pyarrow not imported yet
        with HubServer(tmp / "hub-data") as server, requests.Session() as session:
            base = server.endpoint
            many = f"{base}/datasets/bench/many"
            results["api_info_first_ms"] = _first_ms(session, f"{base}/api/datasets/bench/many")
            results["episodes_first_ms"] = _first_ms(session, f"{many}/episodes")
            results["episode_first_ms"] = _first_ms(session, f"{many}/episodes/500", f"{many}/episodes/500/data.json?rev={sha}")
            rng = random.Random(0)
            urls = {
                "episodes_page_rps": (f"{many}/episodes", None),
                "episode_page_rps": (f"{many}/episodes/{rng.randrange(1000)}", None),
                "pr_page_rps": (f"{base}/{env_id}/discussions/1", HTML),
                "repo_page_matrix_rps": (f"{base}/{env_id}", None),
                "viewer_api_info_rps": (f"{base}/api/models/{env_id}", None),
            }
            _interleaved_rates(session, urls, 5)
            samples: dict[str, list[float]] = {k: [] for k in [*urls, "episode_data_rps"]}
            for _ in range(rounds):
                for key, rate in _interleaved_rates(session, urls, requests_per_round).items():
                    samples[key].append(rate)
                seconds = sum(
                    _get(session, f"{many}/episodes/{rng.randrange(1000)}/data.json?rev={sha}", None)
                    for _ in range(requests_per_round)
                )
                samples["episode_data_rps"].append(requests_per_round / seconds)
            for key, values in samples.items():
                results[key] = statistics.median(values)
            for key in ("episodes_page", "episode_page", "episode_data", "pr_page", "repo_page_matrix"):
                results[f"{key}_vs_api"] = results[f"{key}_rps"] / results["viewer_api_info_rps"]
            for i in range(1000):
                _get(session, f"{many}/episodes/{i}/data.json?rev={sha}", None)
            results["viewer_rss_mb"] = _rss_mb(server.process.pid)
        return results
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run(rounds: int = 5, requests_per_round: int = 100) -> dict:
    from hub_envs import push_env

    tmp = Path(tempfile.mkdtemp(prefix="bench-pages-"))
    try:
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            repo_id = "bench/pendulum-lerobot"
            push_env(REPO_ROOT / "envs" / "pendulum", repo_id, episodes=2, progress=False)
            base = server.endpoint
            urls = {
                "repo_page_rps": (f"{base}/{repo_id}", None),
                "home_page_rps": (f"{base}/", HTML),
                "blob_page_rps": (f"{base}/{repo_id}/blob/main/pendulum_env.py", None),
                "api_info_rps": (f"{base}/api/models/{repo_id}", None),
            }
            results: dict[str, float] = {}
            with requests.Session() as session:
                start = time.perf_counter()
                session.get(f"{base}/{repo_id}", timeout=60).raise_for_status()
                results["repo_page_first_ms"] = 1000 * (time.perf_counter() - start)
                _interleaved_rates(session, urls, 5)  # warm: connection, caches
                samples: dict[str, list[float]] = {k: [] for k in urls}
                for _ in range(rounds):
                    for key, rate in _interleaved_rates(session, urls, requests_per_round).items():
                        samples[key].append(rate)
            for key, values in samples.items():
                results[key] = statistics.median(values)
            results["repo_page_vs_api"] = results["repo_page_rps"] / results["api_info_rps"]
            results["repo_page_rps_4_clients"] = _concurrent_rate(urls["repo_page_rps"][0], 4, requests_per_round)
        results.update(run_viewer(rounds, requests_per_round))
        return results
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--requests", type=int, default=100)
    parser.add_argument("--viewer-only", action="store_true", help="only the dataset viewer and pull request pages")
    args = parser.parse_args()
    results = run_viewer(args.rounds, args.requests) if args.viewer_only else run(args.rounds, args.requests)
    for key, value in results.items():
        print(f"{key:>24}: {value:10.2f}")


if __name__ == "__main__":
    main()
