"""The loopback Hub server, measured through the unmodified ``huggingface_hub`` client.

Measured (median over ``repeats``):

* ``startup_s``: ``HubServer(...)`` — subprocess spawn to first successful HTTP response.
* ``request_ms``: one ``HfApi.model_info`` round trip on a warm connection.
* ``commit_small_ms``: ``create_commit`` of one small file (preupload + commit + the client's checks).
* ``upload_files_per_s``: ``upload_folder`` of ``n_files`` small files in one commit.
* ``snapshot_files_per_s``: ``snapshot_download`` of those files into an empty cache.
* ``upload_mb_per_s`` / ``download_mb_per_s``: one ``size_mb`` MiB file up (inline base64) and down.

Run: ``python benchmarks/bench_server.py [--repeats 5] [--n-files 200] [--size-mb 32]``;
``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from huggingface_hub import CommitOperationAdd, HfApi, hf_hub_download, snapshot_download

from hub_envs.testing import HubServer, hub_environment


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def run(repeats: int = 5, n_files: int = 200, size_mb: int = 32) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="bench-server-"))
    try:
        return _run(tmp, repeats, n_files, size_mb)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _run(tmp: Path, repeats: int, n_files: int, size_mb: int) -> dict:
    results: dict[str, float] = {}

    def start_stop() -> None:
        server = HubServer(tempfile.mkdtemp(dir=tmp))
        server.stop()
        server.remove_log()

    results["startup_s"] = _median_time(start_stop, repeats)

    with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
        api = HfApi(endpoint=server.endpoint)
        api.create_repo("bench/repo")
        api.model_info("bench/repo")
        results["request_ms"] = 1000 * _median_time(lambda: api.model_info("bench/repo"), max(repeats, 20))

        counter = iter(range(10**9))
        results["commit_small_ms"] = 1000 * _median_time(
            lambda: api.create_commit(
                "bench/repo", [CommitOperationAdd(f"small/{next(counter)}.txt", b"x" * 100)], commit_message="small"
            ),
            repeats,
        )

        folder = tmp / "folder"
        for i in range(n_files):
            (folder / f"d{i % 10}").mkdir(parents=True, exist_ok=True)
            (folder / f"d{i % 10}" / f"f{i}.json").write_text(json.dumps({"i": i, "pad": "p" * 500}))
        api.create_repo("bench/many", repo_type="dataset")
        seconds = _median_time(
            lambda: api.upload_folder(
                folder_path=folder, repo_id="bench/many", repo_type="dataset", commit_message=f"{time.time()}"
            ),
            1,
        )
        results["upload_files_per_s"] = n_files / seconds

        caches = iter(range(10**9))
        seconds = _median_time(
            lambda: snapshot_download("bench/many", repo_type="dataset", cache_dir=tmp / f"c{next(caches)}"), repeats
        )
        results["snapshot_files_per_s"] = (n_files + 1) / seconds

        big = os.urandom(size_mb * 1024 * 1024)
        seconds = _median_time(
            lambda: api.create_commit("bench/repo", [CommitOperationAdd("big.bin", big + os.urandom(8))], commit_message="big"),
            max(1, repeats // 2),
        )
        results["upload_mb_per_s"] = size_mb / seconds
        seconds = _median_time(
            lambda: hf_hub_download("bench/repo", "big.bin", cache_dir=tmp / f"c{next(caches)}"),
            max(1, repeats // 2),
        )
        results["download_mb_per_s"] = size_mb / seconds
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--n-files", type=int, default=200)
    parser.add_argument("--size-mb", type=int, default=32)
    args = parser.parse_args()
    for key, value in run(args.repeats, args.n_files, args.size_mb).items():
        print(f"{key:>22}: {value:10.3f}")


if __name__ == "__main__":
    main()
