"""Large files through the loopback Hub's Git LFS path, measured through the unmodified client.

Measured in one run:

* ``server_push_rss_mb``: the server process's peak RSS (``VmHWM``) over a push of ``push_mb`` MiB of
  random files (``upload_folder``, one commit; LFS multipart, streamed to disk). Goal <= 300.
* ``client_push_rss_mb``: the peak RSS of the pushing client (a subprocess) over the same push.
* ``lfs_upload_mb_s`` / ``regular_upload_mb_s``: one ``size_mb`` MiB file committed through LFS, and
  the same size forced inline (base64 in the NDJSON commit: the only path before LFS);
  ``lfs_upload_vs_regular`` is their ratio (> 1: LFS is faster).
* ``lfs_download_mb_s``: ``hf_hub_download`` of that LFS file into an empty cache.
* ``cold_load_big_vs_small``: seconds of a cold ``load_env`` (empty cache) of an env whose dataset is
  ``big_mb`` MiB ÷ the same env with its ~1 MiB dataset (median of ``repeats`` alternating pairs).
  The big variant is pendulum's published repo plus ``big_mb`` MiB of data files listed in its manifest
  (what a camera dataset adds; load_env never parses them). Goal <= 1.1. ``open_dataset_big_s``:
  seconds for ``open_dataset()`` of the big one afterwards (fetch + verify the data).
* ``server_peak_after_inline_mb``: the server's peak RSS once the inline commit has been served too
  (the inline path holds a file's base64 line in memory: what LFS avoids).

Run: ``python -m benchmarks.bench_lfs [--push-mb 1024] [--size-mb 64] [--big-mb 200]``; ``run()``
returns the dict.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from huggingface_hub import CommitOperationAdd, HfApi, hf_hub_download

from benchmarks import PRINT_PEAK_RSS_KIB
from hub_envs.testing import HubServer, add_random_data_files, hub_environment

MiB = 1024 * 1024


def rss_mb(pid: int, field: str = "VmHWM") -> float:
    """``VmHWM`` (peak) or ``VmRSS`` of a process, in MiB (Linux)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no {field} for process {pid}")


def write_random_files(folder: Path, total_mb: int, file_mb: int = 128) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(max(1, total_mb // file_mb)):
        with open(folder / f"episode_{i:03d}.parquet", "wb") as f:
            for _ in range(file_mb):
                f.write(os.urandom(MiB))


def run(push_mb: int = 1024, size_mb: int = 64, big_mb: int = 200, repeats: int = 9) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="bench-lfs-"))
    try:
        # the cold loads first: the 1 GiB push leaves the disk busy writing back for a while
        results = cold_load_big_vs_small(tmp, big_mb, repeats)
        results.update(_run(tmp, push_mb, size_mb))
        return results
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def cold_load_big_vs_small(tmp: Path, big_mb: int, repeats: int) -> dict:
    import json
    import statistics

    from huggingface_hub import snapshot_download

    from hub_envs import load_env, push_env
    from hub_envs.envcode.importing import forget_env_folder, module_key
    from hub_envs.repo import hub_io
    from hub_envs.repo.format import MANIFEST_FILE

    repo_root = Path(__file__).resolve().parent.parent
    with HubServer(tmp / "hub-cold") as server:
        with hub_environment(server.endpoint, tmp / "pusher"):
            small = push_env(repo_root / "envs" / "pendulum", "bench/small", episodes=4, progress=False).sha
            folder = Path(snapshot_download("bench/small", revision=small, local_dir=tmp / "big-repo"))
            shutil.rmtree(folder / ".cache", ignore_errors=True)
            manifest = json.loads((folder / MANIFEST_FILE).read_text())
            manifest["repo_id"] = "bench/big"
            (folder / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2))
            add_random_data_files(folder, max(1, big_mb // 50), 50)
            big = hub_io.publish_folder(folder, "bench/big", parent_commit=None, remote_files=[], message="big dataset")
        times: dict[str, list[float]] = {"small": [], "big": []}
        stages: dict[str, list[dict]] = {"small": [], "big": []}
        for rep in range(repeats + 1):  # the first pair warms up imports and is dropped
            for name in ("small", "big") if rep % 2 == 0 else ("big", "small"):
                sha = small if name == "small" else big
                home = tmp / f"cold-{name}-{rep}"
                with hub_environment(server.endpoint, home):
                    start = time.perf_counter()
                    loaded = load_env(f"bench/{name}@{sha}", trust_remote_code=True)
                    seconds = time.perf_counter() - start
                    loaded.unregister()
                    forget_env_folder(module_key(f"bench/{name}", sha))
                    if rep:
                        times[name].append(seconds)
                        stages[name].append(loaded.report.timings)
                    if rep == repeats and name == "big":
                        start = time.perf_counter()
                        loaded.fetch_dataset()
                        open_big = time.perf_counter() - start
                shutil.rmtree(home, ignore_errors=True)
    ratios = [b / s for b, s in zip(times["big"], times["small"])]
    return {
        "cold_load_small_s": round(statistics.median(times["small"]), 4),
        "cold_load_big_s": round(statistics.median(times["big"]), 4),
        "cold_load_big_vs_small": round(statistics.median(ratios), 3),
        "open_dataset_big_s": round(open_big, 3),
        "cold_load_stages_s": {
            name: {k: round(statistics.median(t.get(k, 0.0) for t in stages[name]), 4) for k in stages[name][0]}
            for name in stages
        },
    }


def _run(tmp: Path, push_mb: int, size_mb: int) -> dict:
    results: dict[str, float] = {}
    folder = tmp / "push"
    write_random_files(folder, push_mb)
    # the inline commit of ``size_mb`` is one base64 line: the server's default cap (16 MiB, a DoS limit) refuses it
    line_cap = {"HUB_ENVS_SERVER_MAX_LINE_MB": str(size_mb * 4 // 3 + 1)}
    with HubServer(tmp / "hub-data", env=line_cap) as server, hub_environment(server.endpoint, tmp / "home"):
        HfApi().create_repo("bench/big")
        results["server_idle_rss_mb"] = rss_mb(server.process.pid, "VmRSS")
        script = (
            textwrap.dedent(
                f"""
            from huggingface_hub import HfApi
            HfApi().upload_folder(folder_path={str(folder)!r}, repo_id="bench/big", commit_message="1 GB")
            """
            )
            + PRINT_PEAK_RSS_KIB
        )
        start = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True, env=os.environ)
        seconds = time.perf_counter() - start
        results["server_push_rss_mb"] = rss_mb(server.process.pid)
        results["client_push_rss_mb"] = int(out.stdout.split()[-1]) / 1024
        results["push_mb_s"] = push_mb / seconds
        shutil.rmtree(folder)

        api = HfApi()
        data = os.urandom(size_mb * MiB)
        start = time.perf_counter()
        sha = api.create_commit("bench/big", [CommitOperationAdd("lfs.bin", data)], commit_message="lfs").oid
        results["lfs_upload_mb_s"] = size_mb / (time.perf_counter() - start)
        regular = CommitOperationAdd("regular.bin", data[::-1])
        regular._upload_mode = "regular"  # the inline path (base64 in the commit), as before LFS
        start = time.perf_counter()
        api.create_commit("bench/big", [regular], commit_message="regular")
        results["regular_upload_mb_s"] = size_mb / (time.perf_counter() - start)
        results["lfs_upload_vs_regular"] = results["lfs_upload_mb_s"] / results["regular_upload_mb_s"]
        start = time.perf_counter()
        hf_hub_download("bench/big", "lfs.bin", revision=sha, cache_dir=tmp / "cache")
        results["lfs_download_mb_s"] = size_mb / (time.perf_counter() - start)
        results["server_peak_after_inline_mb"] = rss_mb(server.process.pid)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--push-mb", type=int, default=1024)
    parser.add_argument("--size-mb", type=int, default=64)
    parser.add_argument("--big-mb", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    for key, value in run(args.push_mb, args.size_mb, args.big_mb, args.repeats).items():
        print(f"{key:>28}: {value:10.2f}" if isinstance(value, (int, float)) else f"{key:>28}: {value}")


if __name__ == "__main__":
    main()
