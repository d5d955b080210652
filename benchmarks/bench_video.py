"""Video datasets: how much smaller, how fast, and how close the decoded frames are.

The reach example env (96x96 camera, 20 fps, 100-step episodes) is rolled out once for ``episodes`` seeds;
the same rollouts are written twice with hub-envs' writer: camera as PNGs in the parquet (dtype ``image``)
and as MP4 encoded by LeRobot's own encoder (dtype ``video``, what ``push_env --video=true`` writes).

* ``video_size_ratio`` = dataset bytes with video ÷ with PNGs (goal <= 0.2; everything under the dataset
  folder counts: data, meta, videos);
* ``video_write_vs_png`` = writing time with video ÷ with PNGs;
* ``video_worst_mean_abs_error`` / ``video_min_psnr_db``: every decoded frame against the rendered one (the
  tolerance replay applies is ``hub_envs.dataset.video.VIDEO_TOLERANCE``).
* the GOP trade-off (details, not goals): per keyframe interval in ``GOPS`` (push_env's default
  ``DEFAULT_VIDEO_GOP`` and LeRobot's 2 among them), the dataset size ratio and the milliseconds LeRobot's
  ``decode_video_frames`` (pyav) takes for one frame at a random timestamp (what a training dataloader does),
  200 samples from the same seeded draw.

Run: ``python -m benchmarks.bench_video [--episodes 20]``; ``run()`` returns the dict.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


GOPS = (2, 4, 10, 20)


def _gop_tradeoff(rollouts, cfg, action, png_bytes: int, samples: int = 200) -> dict:
    """Per GOP: dataset bytes ÷ the PNG dataset's, and ms per randomly accessed frame (LeRobot's decoder)."""
    import random

    from hub_envs._compat import lerobot_video_utils
    from hub_envs.dataset.reader import read_episode_meta
    from hub_envs.dataset.writer import EpisodeFrames, dataset_features_from_config, rollout_to_frames, write_lerobot_dataset

    decode = lerobot_video_utils().decode_video_frames
    key = cfg.features_map["pixels"]
    out = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench-gop-"))
    try:
        for gop in GOPS:
            root = tmp / f"gop{gop}"
            write_lerobot_dataset(
                root,
                repo_id="bench/reach",
                fps=int(cfg.fps),
                features=dataset_features_from_config(cfg, action=action, video=True),
                episodes=(EpisodeFrames(r.index, r.seed, rollout_to_frames(r, cfg.features_map)) for r in rollouts),
                task=str(cfg.task),
                progress=False,
                video_gop=gop,
            )
            metas = read_episode_meta(root)
            rng = random.Random(0)
            t = time.perf_counter()
            for _ in range(samples):
                m = rng.choice(metas)
                path = (
                    root / f"videos/{key}/chunk-{m[f'videos/{key}/chunk_index']:03d}/file-{m[f'videos/{key}/file_index']:03d}.mp4"
                )
                ts = m[f"videos/{key}/from_timestamp"] + rng.randrange(int(m["length"])) / int(cfg.fps)
                decode(path, [ts], 1e-4, backend="pyav")
            out[str(gop)] = {
                "size_ratio": round(_size(root) / png_bytes, 4),
                "random_frame_ms": round(1000 * (time.perf_counter() - t) / samples, 2),
            }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def run(episodes: int = 20) -> dict:
    from hub_envs import load_env
    from hub_envs.dataset.reader import read_episode_frames
    from hub_envs.dataset.video import VIDEO_TOLERANCE, frame_errors, psnr
    from hub_envs.dataset.writer import EpisodeFrames, dataset_features_from_config, rollout_to_frames, write_lerobot_dataset
    from hub_envs.harness.actions import stored_action
    from hub_envs.harness.rollout import run_episodes

    loaded = load_env(ROOT / "envs" / "reach", check=False)
    cfg = loaded.config
    try:
        probe = loaded.make()
        action = stored_action(probe.action_space)
        probe.close()
        t = time.perf_counter()
        rollouts = run_episodes(loaded.make, list(range(episodes)), max_steps=int(cfg.episode_length), progress=False)
        rollout_s = time.perf_counter() - t
    finally:
        loaded.unregister()
    out: dict = {
        "env": "reach",
        "episodes": episodes,
        "frames": sum(r.length for r in rollouts),
        "rollout_s": round(rollout_s, 2),
    }
    tmp = Path(tempfile.mkdtemp(prefix="bench-video-"))
    try:
        for video in (False, True):
            root = tmp / ("video" if video else "png")
            features = dataset_features_from_config(cfg, action=action, video=video)
            t = time.perf_counter()
            write_lerobot_dataset(
                root,
                repo_id="bench/reach",
                fps=int(cfg.fps),
                features=features,
                episodes=(EpisodeFrames(r.index, r.seed, rollout_to_frames(r, cfg.features_map)) for r in rollouts),
                task=str(cfg.task),
                progress=False,
            )
            name = "video" if video else "png"
            out[f"{name}_write_s"] = round(time.perf_counter() - t, 2)
            out[f"{name}_bytes"] = _size(root)
        key = cfg.features_map["pixels"]
        errs, psnrs = [], []
        t = time.perf_counter()
        for r in rollouts:
            decoded = read_episode_frames(tmp / "video", r.index, keys=[key])[key]
            errs.append(frame_errors(decoded, r.observations["pixels"]))
            psnrs.append(psnr(decoded, r.observations["pixels"]))
        out["video_decode_s"] = round(time.perf_counter() - t, 2)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out["gops"] = _gop_tradeoff(rollouts, cfg, action, out["png_bytes"])
    errs_all, psnr_all = np.concatenate(errs), np.concatenate(psnrs)
    out["video_size_ratio"] = round(out["video_bytes"] / out["png_bytes"], 4)
    from hub_envs.dataset.video import DEFAULT_VIDEO_GOP

    out["video_gop"] = DEFAULT_VIDEO_GOP
    out["video_size_ratio_lerobot_gop"] = out["gops"]["2"]["size_ratio"]
    out["video_random_frame_ms"] = out["gops"][str(DEFAULT_VIDEO_GOP)]["random_frame_ms"]
    out["video_random_frame_ms_lerobot_gop"] = out["gops"]["2"]["random_frame_ms"]
    out["video_write_vs_png"] = round(out["video_write_s"] / out["png_write_s"], 3)
    out["video_worst_mean_abs_error"] = round(float(errs_all.max()), 3)
    out["video_median_mean_abs_error"] = round(float(np.median(errs_all)), 3)
    out["video_min_psnr_db"] = round(float(psnr_all.min()), 2)
    out["video_tolerance"] = VIDEO_TOLERANCE.to_dict()
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    print(json.dumps(run(args.episodes), indent=2))
