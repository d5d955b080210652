"""Pictures of an env for its card: a GIF (and an MP4) of a few random-action rollouts, from ``env.render()``.

Card media must be big enough to see: at least :data:`MIN_WIDTH` px wide, rendered at that size by the env
itself, not upscaled. :func:`render_size_overrides` finds the env's render-size knob among its gym kwargs
(LeRobot's ``visualization_width``/``visualization_height``, ``render_width``/``render_height``, or
``observation_width``/``observation_height`` for envs whose ``render()`` is their camera) and asks for
:data:`MIN_WIDTH` px; an env without such a knob renders at its own size and frames narrower than
:data:`MIN_WIDTH` are enlarged by whole-pixel repetition (crisp pixels, no interpolation). The GIF plays
at the env's real fps (frames subsampled to at most ~15 per second, each shown for its sim time).

What the picture shows is the env's ``render()``: its author frames it for the card with keyword arguments in
``pyproject.toml`` (``[tool.hub-envs.media] gym_kwargs``, e.g. a camera that follows the robot, as gymnasium's
MuJoCo envs take ``default_camera_config``); :func:`card_media_kwargs` adds the render size to them, and the card
states the result, so the media can be rendered again from the repo alone.

Example:
    >>> render_size_overrides({"fps": 20, "observation_height": 96, "observation_width": 96})
    {'observation_width': 256, 'observation_height': 256}
    >>> render_size_overrides({"render_width": 640, "render_height": 480})
    {}
    >>> card_media_kwargs({"render_width": 128, "render_height": 128}, {"render_camera": {"target": "drone"}})
    {'render_camera': {'target': 'drone'}, 'render_width': 256, 'render_height': 256}
    >>> from hub_envs.harness.media import write_rollout_media
    >>> write_rollout_media(loaded.make, "media/rollout.gif", seeds=[0, 1, 2], fps=30)   # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs.dataset.video import encode_episode
from hub_envs.errors import EnvCodeError
from hub_envs.harness.episode import SeededEpisode

MIN_WIDTH = 256  # px: visible on a Hub page
MAX_SIDE = 512  # px: larger renders are subsampled, so GIFs stay a few MB
GIF_MAX_FPS = 15  # frames per second of the GIF (the env's time is kept: each frame lasts its sim time)
MEDIA_EPISODES, MEDIA_STEPS = 3, 60  # the card's media: the first 3 dataset episodes, up to 60 steps each
#: gym kwargs that set what ``render()`` returns, in the order they are looked for
RENDER_SIZE_KNOBS = (
    ("visualization_width", "visualization_height"),  # LeRobot's PushT / gym-pusht
    ("render_width", "render_height"),
    ("observation_width", "observation_height"),  # envs whose render() is their camera
)


def render_size_overrides(gym_kwargs: Mapping[str, Any], min_width: int = MIN_WIDTH) -> dict[str, int]:
    """The gym kwargs that make the env render at least ``min_width`` px wide (same aspect), or ``{}``.

    Args:
        gym_kwargs: the keyword arguments the env is made with (its config's ``gym_kwargs``).
        min_width: the narrowest render wanted, in pixels.

    Returns:
        The first render-size pair of :data:`RENDER_SIZE_KNOBS` that ``gym_kwargs`` sets, scaled up to ``min_width``;
        ``{}`` when it is wide enough already or the env has no such knob.
    """
    for wk, hk in RENDER_SIZE_KNOBS:
        w, h = gym_kwargs.get(wk), gym_kwargs.get(hk)
        if isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0:
            if w >= min_width:
                return {}
            return {wk: int(min_width), hk: int(round(h * min_width / w))}
    return {}


def card_media_kwargs(gym_kwargs: Mapping[str, Any], media_gym_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The keyword arguments the card's media are rendered with: the author's ``[tool.hub-envs.media] gym_kwargs``
    (``media_gym_kwargs``), then the render size :func:`render_size_overrides` asks for (at least :data:`MIN_WIDTH`
    px wide, the author's own size knob taken into account). ``{}`` means the env as its config makes it.

    Args:
        gym_kwargs: the keyword arguments the env is made with (its config's ``gym_kwargs``).
        media_gym_kwargs: the author's ``[tool.hub-envs.media] gym_kwargs``, if any.

    Returns:
        The keyword arguments to add to ``gym_kwargs`` for the env that renders the card's media.
    """
    author = dict(media_gym_kwargs or {})
    return {**author, **render_size_overrides({**gym_kwargs, **author})}


def _fit(frame: np.ndarray) -> np.ndarray:
    h, w = frame.shape[:2]
    if max(h, w) > MAX_SIDE:
        step = int(np.ceil(max(h, w) / MAX_SIDE))
        return frame[::step, ::step]
    if w < MIN_WIDTH:  # no render-size knob: whole-pixel repetition, no interpolation blur
        k = int(np.ceil(MIN_WIDTH / w))
        return np.repeat(np.repeat(frame, k, axis=0), k, axis=1)
    return frame


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
    return _fit(np.ascontiguousarray(frame[..., :3]))


def rollout_frames(make_env: Callable[[], Any], *, seeds: list[int], max_steps: int, every: int = 1) -> list[np.ndarray]:
    """Rendered frames of seeded random-action episodes (:class:`SeededEpisode`), one per seed in turn.

    Args:
        make_env: builds the env (in ``rgb_array`` render mode); it is closed before this returns.
        seeds: the reset seeds, one episode each.
        max_steps: the longest an episode runs.
        every: render every ``every``-th step (see :func:`media_step`).

    Returns:
        The frames, (H, W, 3) uint8, at most :data:`MAX_SIDE` px and at least :data:`MIN_WIDTH` px wide.

    Raises:
        EnvCodeError: ``render()`` raised or returned something other than an (H, W, 3) uint8 array.
    """
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


def media_step(fps: int) -> int:
    """Render every ``media_step(fps)``-th step: the smallest divisor of ``fps`` that gives at most
    :data:`GIF_MAX_FPS` frames per second (an integer frame rate, so the MP4 plays at the env's real speed).

    Args:
        fps: the env's frames per second (its config's ``fps``).

    Returns:
        The step between two rendered frames.

    >>> media_step(20), media_step(30), media_step(50), media_step(7)
    (2, 2, 5, 1)
    """
    fps = max(int(fps), 1)
    return next(d for d in range(1, fps + 1) if fps % d == 0 and fps // d <= GIF_MAX_FPS)


def write_rollout_media(
    make_env: Callable[[], Any],
    gif_path: str | Path,
    *,
    seeds: list[int],
    fps: int,
    max_steps: int = 60,
    mp4_path: str | Path | None = None,
) -> list[Path]:
    """Render random-action rollouts of ``seeds`` to a looping GIF at the env's real speed (deterministic bytes for
    the same frames) and, with ``mp4_path``, to an MP4 of the same frames (LeRobot's video encoder).

    Args:
        make_env: builds the env that renders (see :func:`card_media_kwargs` for its keyword arguments).
        gif_path: where the GIF goes (its folder is created).
        seeds: the reset seeds, one episode each.
        fps: the env's frames per second; the media play at that speed (see :func:`media_step`).
        max_steps: the longest an episode runs.
        mp4_path: where the MP4 goes, or None for no MP4.

    Returns:
        The files written: the GIF, then the MP4 if asked for.

    Raises:
        EnvCodeError: the env's ``render()`` failed (see :func:`rollout_frames`).
        DatasetError: the frames could not be encoded as video.
    """
    import imageio.v3 as iio  # heavy: imageio

    fps = max(int(fps), 1)
    every = media_step(fps)
    frames = np.stack(rollout_frames(make_env, seeds=seeds, max_steps=max_steps, every=every))
    gif_path = Path(gif_path)
    gif_path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(gif_path, frames, extension=".gif", duration=int(round(1000 * every / fps)), loop=0)
    written = [gif_path]
    if mp4_path is not None:
        h, w = (frames.shape[1] // 2) * 2, (frames.shape[2] // 2) * 2  # yuv420p needs even sizes
        encode_episode(np.ascontiguousarray(frames[:, :h, :w]), Path(mp4_path), fps // every)
        written.append(Path(mp4_path))
    return written
