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

Requests per second of one client, sequential, the requests of the four URLs interleaved one by one
(so that each sees the same load on a shared machine): the median over ``rounds`` rounds of
``requests`` requests to each URL. Run: ``python -m benchmarks.bench_pages [--rounds 5] [--requests 100]``.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import threading
import time
from pathlib import Path

import requests

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
            return results
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--requests", type=int, default=100)
    args = parser.parse_args()
    for key, value in run(args.rounds, args.requests).items():
        print(f"{key:>24}: {value:10.2f}")


if __name__ == "__main__":
    main()
