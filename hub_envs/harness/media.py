"""Pictures of an env: a GIF of a few random-action rollouts, from ``env.render()``.

Example:
    >>> from hub_envs.harness.media import write_rollout_gif
    >>> write_rollout_gif(lambda: loaded.make(), "rollout.gif", seeds=[0, 1], fps=30)   # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs.errors import EnvCodeError
from hub_envs.harness.episode import SeededEpisode

MAX_SIDE = 160  # px: cards load fast, GIFs stay small


def _downscale(frame: np.ndarray) -> np.ndarray:
    h, w = frame.shape[:2]
    step = int(np.ceil(max(h, w) / MAX_SIDE))
    return frame[::step, ::step] if step > 1 else frame


def _frame(env: Any) -> np.ndarray:
    try:
        frame = env.render()
    except Exception as exc:
        raise EnvCodeError(
            f"env.render() raised {type(exc).__name__}: {exc}. Publishing renders the card's GIF, so "
            f"what render() needs (e.g. pygame) must be installed and listed in the env's "
            f"[project] dependencies."
        ) from exc
    if not (isinstance(frame, np.ndarray) and frame.ndim == 3 and frame.dtype == np.uint8):
        raise EnvCodeError(
            f"env.render() must return an (H, W, 3) uint8 array in rgb_array mode, got "
            f"{type(frame).__name__} {getattr(frame, 'shape', '')} {getattr(frame, 'dtype', '')}."
        )
    return _downscale(frame[..., :3])


def rollout_frames(make_env: Callable[[], Any], *, seeds: list[int], max_steps: int, every: int = 1) -> list[np.ndarray]:
    """Rendered frames of seeded random-action episodes (:class:`SeededEpisode`), one per seed in turn."""
    frames = []
    env = make_env()
    try:
        for seed in seeds:
            episode = SeededEpisode(env, seed)
            while episode.t < max_steps and not episode.done:
                if episode.t % every == 0:
                    frames.append(_frame(env))
                episode.step(episode.sample())
    finally:
        env.close()
    return frames


def write_rollout_gif(make_env: Callable[[], Any], path: str | Path, *, seeds: list[int], fps: int, max_steps: int = 90) -> Path:
    """Render random-action rollouts of ``seeds`` to a looping GIF (deterministic bytes for the same frames)."""
    import imageio.v3 as iio

    every = max(1, fps // 15)  # ~15 frames per second of sim time
    frames = rollout_frames(make_env, seeds=seeds, max_steps=max_steps, every=every)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), extension=".gif", duration=int(1000 * every / max(fps, 1)), loop=0)
    return path
