"""The loopback server under concurrent downloads: N clients ``snapshot_download`` one repo at once.

A repo of ``n_files`` random files (``size_mb`` MiB in all) is committed once. Each repeat starts
``clients`` processes (forked), each with its own empty Hugging Face cache, releases them together and
waits for all; every downloaded file is compared with what was uploaded (sha256).

* ``server_download_mb_s``: total MiB delivered to all clients ÷ wall time of the repeat (median).
* ``server_errors``: downloads that raised, plus files whose bytes differ (sum over repeats). Goal 0.

Run: ``python -m benchmarks.bench_download [--clients 8] [--size-mb 32] [--repeats 3]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import multiprocessing
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path


def _client(barrier, queue, endpoint: str, cache: str, expected: dict[str, str]) -> None:
    from huggingface_hub import snapshot_download
    from huggingface_hub.utils import disable_progress_bars

    disable_progress_bars()
    barrier.wait()
    try:
        path = Path(snapshot_download("bench/blobs", cache_dir=cache, endpoint=endpoint))
        bad = sum(hashlib.sha256((path / name).read_bytes()).hexdigest() != digest for name, digest in expected.items())
        queue.put(("ok", bad))
    except Exception as e:  # noqa: BLE001
        queue.put(("error", f"{type(e).__name__}: {e}"))


def run(clients: int = 8, size_mb: int = 32, n_files: int = 4, repeats: int = 3, verbose: bool = True) -> dict:
    from huggingface_hub import CommitOperationAdd, HfApi

    from hub_envs.testing import HubServer, hub_environment

    tmp = Path(tempfile.mkdtemp(prefix="bench-download-"))
    ctx = multiprocessing.get_context("fork")
    rates, errors, messages = [], 0, []
    try:
        with HubServer(tmp / "hub-data") as server, hub_environment(server.endpoint, tmp / "home"):
            api = HfApi(endpoint=server.endpoint)
            api.create_repo("bench/blobs")
            per_file = size_mb * 2**20 // n_files
            blobs = {f"blob-{i}.bin": os.urandom(per_file) for i in range(n_files)}
            api.create_commit("bench/blobs", [CommitOperationAdd(k, v) for k, v in blobs.items()], commit_message="blobs")
            expected = {k: hashlib.sha256(v).hexdigest() for k, v in blobs.items()}
            total_mb = clients * per_file * n_files / 2**20
            for rep in range(repeats):
                barrier, queue = ctx.Barrier(clients + 1), ctx.Queue()
                procs = [
                    ctx.Process(target=_client, args=(barrier, queue, server.endpoint, str(tmp / f"c{rep}-{i}"), expected))
                    for i in range(clients)
                ]
                for p in procs:
                    p.start()
                barrier.wait()
                t = time.perf_counter()
                outcomes = [queue.get(timeout=600) for _ in procs]
                seconds = time.perf_counter() - t
                for p in procs:
                    p.join(30)
                for status, value in outcomes:
                    if status == "ok":
                        errors += value
                    else:
                        errors += 1
                        messages.append(value)
                rates.append(total_mb / seconds)
                for i in range(clients):
                    shutil.rmtree(tmp / f"c{rep}-{i}", ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    results = {
        "clients": clients,
        "repo_mb": size_mb,
        "files": n_files,
        "repeats": repeats,
        "per_repeat_mb_s": [round(r, 1) for r in rates],
        "server_download_mb_s": round(statistics.median(rates), 1),
        "server_errors": errors,
        "error_messages": messages[:5],
    }
    if verbose:
        print(
            f"{clients} concurrent snapshot_downloads of {size_mb} MiB: {results['server_download_mb_s']} MiB/s, {errors} errors",
            flush=True,
        )
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--size-mb", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(json.dumps(run(args.clients, args.size_mb, repeats=args.repeats), indent=2))


if __name__ == "__main__":
    main()
