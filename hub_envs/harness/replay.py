"""Replay a recorded dataset in an env and compare every step: does the env still produce the data?

One concept: a *replay* resets the env with each episode's recorded seed, applies the recorded
actions (the rollout engine with one action array per episode, in parallel across processes), and
compares what comes out with what the dataset holds, frame by frame: every observation the config's
``features_map`` maps to a dataset key (images too), ``next.reward``, ``next.done``,
``next.success`` and, when push_env recorded them (:mod:`hub_envs.dataset.states`), the simulator states.
Exactly by default; within an absolute ``tolerance`` if one is given (booleans are always exact).
Video features (dtype ``"video"``, lossy-encoded) are the one exception: a frame matches when its mean
absolute difference from the decoded frame is within :data:`hub_envs.dataset.video.VIDEO_TOLERANCE`. The
rendered frames are also checked bit for bit against the sha256 push recorded of them
(``EpisodeReplay.video_exact``): when they are the recorded ones, only the video's keyframes are decoded and
compared within the tolerance, which shows the file holds those frames; otherwise every frame is.

A frame ``t`` holds the observation *before* action ``t`` and the reward/done/success *after* it,
so a changed transition at step ``t`` shows in ``next.*`` at frame ``t`` and in the observations at
frame ``t + 1``. Each diverged episode is then *localized* (robomimic's playback):

* with recorded states: every step is replayed from its recorded state (``reset_to(states[t])``,
  ``step(actions[t])``, compare with frame ``t + 1``), which separates a change in the dynamics at
  step ``t`` from an error carried over from earlier steps: "playback diverged by {err} at step {t}";
* without them, if the env has ``get_state``/``reset_to``: the replay's own state before the first
  diverging step is restored in a fresh env, which must reproduce the diverging step, so the
  difference is in that transition and not in hidden state or non-determinism.

Example:
    >>> from hub_envs.harness.replay import replay_dataset                                   # doctest: +SKIP
    >>> result = replay_dataset(loaded.make, loaded.dataset_root, loaded.config.features_map)  # doctest: +SKIP
    >>> result.ok, result.first_divergence                                          # doctest: +SKIP
    (False, Divergence(episode=0, step=1, feature='observation.state', ...))
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs._compat import LEROBOT_VIDEO_GOP, video_gop
from hub_envs.dataset.layout import FRAMES_SHA256_COLUMN, NEXT_KEYS, STATE_FEATURE
from hub_envs.dataset.reader import DatasetFrames, read_episode_meta, read_hub_envs_meta, read_info
from hub_envs.dataset.states import read_env_states
from hub_envs.dataset.video import VIDEO_TOLERANCE, decode_episode, encode_episode, frame_errors, frames_sha256
from hub_envs.dataset.writer import rollout_to_frames
from hub_envs.errors import DatasetError, HubEnvsError, ReproductionError
from hub_envs.harness.actions import to_env_actions
from hub_envs.harness.rollout import flatten_observation, iter_episodes, run_episodes

__all__ = ["Divergence", "EpisodeReplay", "ReplayResult", "Replay", "replay_dataset", "STATE_FEATURE"]

#: Diverged episodes localized by state-restored playback (each costs one more pass over the episode)
#: and whose per-step error curves are kept in the report.
MAX_LOCALIZED = 3


# --- results ----------------------------------------------------------------------------------


@dataclass
class Divergence:
    """The first step at which one feature of one episode differs by more than the tolerance."""

    episode: int
    seed: int | None
    step: int  # frame index in the episode
    feature: str  # dataset key (``observation.state``, ``next.reward``, ...) or ``env_state``
    env_key: str | None  # the env-side name, when the feature is an observation
    max_abs_diff: float
    element: list[int]  # index (within the frame) of the largest difference
    dataset: Any  # the dataset's value there (a list; images: a short summary)
    replay: Any  # the replay's value
    note: str = ""

    def describe(self) -> str:
        where = f"episode {self.episode}" + (f" (seed {self.seed})" if self.seed is not None else "")
        at = f"[{', '.join(map(str, self.element))}]" if self.element else ""
        text = (
            f"{where}, {self.feature}{at}: playback diverged by {self.max_abs_diff:.6g} "
            f"at step {self.step} (dataset {_short(self.dataset)} vs replay {_short(self.replay)})"
        )
        return text + (f"; {self.note}" if self.note else "")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class EpisodeReplay:
    """The replay of one episode."""

    episode: int
    seed: int | None
    length: int  # frames in the dataset
    replay_length: int  # frames the replay produced (one more if the env did not end where the data did)
    divergences: list[Divergence] = field(default_factory=list)  # first divergence of each feature, by step
    max_abs_diff: dict[str, float] = field(default_factory=dict)  # over the whole episode, per feature
    error_curve: dict[str, list[float]] = field(default_factory=dict)  # per-step max |diff| (diverged episodes)
    localization: dict[str, Any] | None = None
    #: per video feature: the replayed frames are the recorded ones bit for bit: their sha256 is the one push
    #: recorded (``frames_sha256/<key>``), or, for a dataset that records none, encoded with the same
    #: (deterministic) encoder they decode to exactly the dataset's frames
    video_exact: dict[str, bool] = field(default_factory=dict)
    #: per video feature: each frame's mean |replay - decoded| (0-255), every frame of the episode; NaN where a frame
    #: was not decoded (an episode rendered bit for bit decodes its keyframes only). For the report's plot, not its JSON
    #: (a float per frame: unbounded)
    video_errors: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)
    video_exact_by: dict[str, str] = field(default_factory=dict)  # per video feature: "frames_sha256" or "reencode"
    #: per video feature: the frames decoded and compared within the tolerance (all of them, or the keyframes of
    #: an episode rendered bit for bit)
    video_checked: dict[str, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.divergences

    @property
    def first(self) -> Divergence | None:
        return self.divergences[0] if self.divergences else None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(replace(self, video_errors={}))
        del d["video_errors"]
        d["ok"] = self.ok
        return d


@dataclass
class ReplayResult:
    """Every episode's replay, and what was compared."""

    episodes: list[EpisodeReplay]
    tolerance: float
    features: dict[str, str | None]  # compared dataset key -> env-side key (None for next.* and env_state)
    skipped: dict[str, str]  # dataset key -> why it was not compared
    states: str  # how recorded states were used
    steps: int  # env steps taken by the open-loop replay
    seconds: float
    video: dict[str, Any] | None = None  # video features compared: keys, the tolerance (VideoTolerance.to_dict()), worst, mean

    @property
    def ok(self) -> bool:
        return all(e.ok for e in self.episodes)

    @property
    def diverged(self) -> list[EpisodeReplay]:
        return [e for e in self.episodes if not e.ok]

    @property
    def first_divergence(self) -> Divergence | None:
        firsts = [e.first for e in self.episodes if e.first is not None]
        return firsts[0] if firsts else None

    def summary(self) -> str:
        n = len(self.episodes)
        frames = sum(e.length for e in self.episodes)
        how = "exactly" if self.tolerance == 0 else f"within {self.tolerance:g}"
        if self.ok:
            videos = set(self.video["keys"]) if self.video else set()
            exact = ", ".join(k for k in self.features if k not in videos)
            text = f"replay: all {n} episodes ({frames} frames) reproduce {how} ({exact})"
            if self.video:
                v = self.video
                text += (
                    f", video {', '.join(v['keys'])} within mean abs error "
                    f"{v['tolerance']['max_mean_abs_error']:g}/255 per frame (worst {v['worst']:.3g}"
                    + (
                        f" in the {v['frames_checked']} of {v['frames']} frames decoded"
                        if v["frames_checked"] < v["frames"]
                        else ""
                    )
                    + (_BIT_EXACT_TEXT.get(v["bit_exact_by"], "; bit for bit") if v["bit_exact"] else "")
                    + ")"
                )
            return text
        first = self.first_divergence
        return f"replay: {len(self.diverged)} of {n} episodes diverge; first: {first.describe()}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "tolerance": self.tolerance,
            "features": self.features,
            "skipped": self.skipped,
            "states": self.states,
            "video": self.video,
            "episodes_total": len(self.episodes),
            "episodes_diverged": [e.episode for e in self.diverged],
            "frames": sum(e.length for e in self.episodes),
            "steps": self.steps,
            "seconds": self.seconds,
            "first_divergence": self.first_divergence.to_dict() if self.first_divergence else None,
            "episodes": [e.to_dict() for e in self.episodes],
        }


# --- comparing arrays -------------------------------------------------------------------------


def _short(value: Any, limit: int = 100) -> str:
    """A value for a message: floats with 9 significant digits (float32 round-trips), long lists cut."""

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.9g}"
        if isinstance(v, list):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        return str(v)

    text = fmt(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _as_dataset_layout(replay: np.ndarray, data: np.ndarray, image: bool) -> np.ndarray:
    """Bring a replayed array to the dataset's layout and dtype (what the dataset writer does)."""
    if image:
        if (
            replay.ndim == 4
            and replay.shape[1:] != data.shape[1:]
            and replay.shape[1:] == (data.shape[3], data.shape[1], data.shape[2])
        ):
            replay = replay.transpose(0, 2, 3, 1)  # channel-first env images are stored channel-last
        if replay.dtype.kind == "f":
            replay = (replay * 255).astype(np.uint8)
    if replay.shape[1:] != data.shape[1:] and replay.size == data.size // max(len(data), 1) * len(replay):
        replay = replay.reshape(len(replay), *data.shape[1:])
    if replay.dtype != data.dtype:
        replay = replay.astype(data.dtype)
    return replay


def step_errors(replay: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Per-frame max |replay - data| as float64 (booleans: 0 or 1; NaN vs NaN counts as equal).

    Equality is tested first (cheap, no conversion); magnitudes are computed only for frames that differ.

    Args:
        replay: the replayed values, one row per frame, in ``data``'s layout (same frame count).
        data: the recorded values, one row per frame.

    Returns:
        One float64 per frame: 0 where the frame is equal, else its largest absolute difference (``inf`` where
        only one side is NaN).
    """
    n = len(data)
    errors = np.zeros(n)
    if n == 0:
        return errors
    a = replay.reshape(n, -1)
    b = data.reshape(n, -1)
    differ = (a != b).any(axis=1)
    if not differ.any():
        return errors
    rows = np.flatnonzero(differ)
    a, b = a[rows], b[rows]
    if a.dtype.kind == "b" or b.dtype.kind == "b":
        errors[rows] = 1.0
        return errors
    diff = np.abs(a.astype(np.float64) - b.astype(np.float64))
    if a.dtype.kind == "f" and b.dtype.kind == "f":
        diff[np.isnan(a) & np.isnan(b)] = 0.0
    diff[np.isnan(diff)] = np.inf
    errors[rows] = diff.max(axis=1)
    return errors


def _value(arr: np.ndarray, image: bool) -> Any:
    if image:
        return f"image {tuple(arr.shape)} mean {float(arr.mean()):.2f}"
    if arr.shape == (1,):  # LeRobot stores scalars (reward, done) as shape (1,)
        return arr[0].item()
    return arr.tolist()


def _element(replay_frame: np.ndarray, data_frame: np.ndarray) -> list[int]:
    if replay_frame.ndim == 0 or replay_frame.shape == (1,):
        return []
    a = replay_frame.astype(np.float64) if replay_frame.dtype.kind != "b" else replay_frame.astype(np.float64)
    b = data_frame.astype(np.float64)
    diff = np.abs(a - b)
    diff[np.isnan(diff)] = np.inf
    return [int(i) for i in np.unravel_index(int(np.argmax(diff)), diff.shape)]


# --- the replay -------------------------------------------------------------------------------


@dataclass
class _Plan:
    root: Path
    features: dict[str, str | None]  # dataset key -> env key
    image_keys: set[str]  # images and videos (uint8 frames)
    video_keys: set[str]  # compared within VIDEO_TOLERANCE
    skipped: dict[str, str]
    action_key: str
    metas: list[dict]
    seeds: list[int]
    actions: list[np.ndarray]  # as recorded, per episode
    states: dict[int, np.ndarray] | None
    frames: DatasetFrames
    fps: int = 1
    video_gops: dict[str, int] = field(default_factory=dict)  # video key -> the GOP its MP4s were encoded with


def _plan(dataset_root: Path, features_map: Mapping[str, str], episodes: list[int] | None) -> _Plan:
    info = read_info(dataset_root)
    ds_features = info["features"]
    metas = read_episode_meta(dataset_root)
    if episodes is not None:
        wanted = set(episodes)
        unknown = sorted(wanted - {m["episode_index"] for m in metas})
        if unknown:
            raise ReproductionError(f"{dataset_root}: episodes {unknown} are not in the dataset ({len(metas)} episodes).")
        metas = [m for m in metas if m["episode_index"] in wanted]
    recorded_seeds = read_hub_envs_meta(dataset_root, info).get("seeds") or []
    seeds = []
    for m in metas:
        seed = m.get("seed")
        if seed is None and m["episode_index"] < len(recorded_seeds):
            seed = recorded_seeds[m["episode_index"]]
        if seed is None:
            raise ReproductionError(
                f"{dataset_root}: episode {m['episode_index']} records no reset seed (neither the episodes metadata nor "
                f"info.json hub_envs.seeds), so it cannot be replayed. Datasets written by push_env record them."
            )
        seeds.append(int(seed))
    action_key = features_map.get("action", "action")
    if action_key not in ds_features:
        raise ReproductionError(
            f"{dataset_root}: the dataset has no '{action_key}' feature (features_map['action']); nothing to replay."
        )
    features: dict[str, str | None] = {}
    skipped: dict[str, str] = {}
    mapped = {v: k for k, v in features_map.items() if k != "action"}
    for key in ds_features:
        if key in mapped:
            features[key] = mapped[key]
        elif key in NEXT_KEYS:
            features[key] = None
        elif key not in ("timestamp", "frame_index", "episode_index", "index", "task_index", action_key):
            skipped[key] = "not in the config's features_map"
    image_keys = {k for k in features if ds_features[k].get("dtype") in ("image", "video")}
    video_keys = {k for k in features if ds_features[k].get("dtype") == "video"}
    frames = DatasetFrames(Path(dataset_root), info, metas, [action_key, *features])
    actions = [frames.numeric[m["episode_index"]][action_key] for m in metas]
    states = read_env_states(dataset_root)
    if states is not None:
        missing = [
            m["episode_index"]
            for m in metas
            if m["episode_index"] not in states or len(states[m["episode_index"]]) != m["length"]
        ]
        if missing:
            raise DatasetError(
                f"{dataset_root}: the recorded env states do not cover episodes {missing}. Re-publish the env with push_env."
            )
    return _Plan(
        Path(dataset_root),
        features,
        image_keys,
        video_keys,
        skipped,
        action_key,
        metas,
        seeds,
        actions,
        states,
        frames,
        int(info.get("fps") or 1),
        {k: video_gop(ds_features[k].get("info")) for k in video_keys},
    )


def env_actions(actions: np.ndarray, space: Any, where: str) -> np.ndarray:
    """Recorded actions in the layout and dtype of the env's action space (:func:`hub_envs.harness.actions.to_env_actions`).

    Args:
        actions: the dataset's actions of one episode, one row per step.
        space: the env's action space.
        where: the episode, as the error message names it (e.g. ``"episode 3 (seed 3)"``).

    Returns:
        The actions as the env takes them (integers for discrete spaces, the space's shape per step).

    Raises:
        ReproductionError: the recorded actions do not fit the action space (the env changed it since).
    """
    shape = tuple(getattr(space, "shape", None) or ())
    if actions.shape[1:] != shape and int(np.prod(actions.shape[1:])) != int(np.prod(shape)):
        raise ReproductionError(
            f"{where}: the recorded actions have shape {actions.shape[1:]} but the env's action space is {space}. "
            f"The env changed its action space since the data was recorded."
        )
    return to_env_actions(actions, space)


def _compare_episode(
    plan: _Plan,
    pos: int,
    rollout: Any,
    data: dict[str, np.ndarray],
    features_map: Mapping[str, str],
    tolerance: float,
    keep_curves: bool,
    keyframes: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> EpisodeReplay:
    """Compare one episode's rollout with its dataset frames ``data``. A video feature missing from ``data`` has its
    ``keyframes`` (:meth:`DatasetFrames.video_keyframes`) there instead: when the rendered frames' sha256 is the
    recorded one, those are decoded frames enough (each within the tolerance); otherwise every frame is decoded."""
    meta = plan.metas[pos]
    ep, seed, length = meta["episode_index"], plan.seeds[pos], int(meta["length"])
    replay = rollout_to_frames(rollout, features_map)
    result = EpisodeReplay(episode=ep, seed=seed, length=length, replay_length=rollout.length)
    keyframes = keyframes or {}
    pairs: list[tuple[str, np.ndarray | None, np.ndarray | None]] = [(k, replay.get(k), data.get(k)) for k in plan.features]
    if plan.states is not None:
        pairs.append((STATE_FEATURE, rollout.states, plan.states[ep]))
    curves: dict[str, np.ndarray] = {}

    def whole(key: str, dataset: Any, replay: Any, note: str) -> None:
        """A divergence of the whole feature (gone, or another shape): from step 0, no element."""
        result.divergences.append(
            Divergence(ep, seed, 0, key, plan.features.get(key), float("inf"), [], dataset, replay, note=note)
        )

    for key, rep, dat in pairs:
        video = key in plan.video_keys
        limit = max(tolerance, VIDEO_TOLERANCE.max_mean_abs_error) if video else tolerance
        if (
            video
            and rep is not None
            and dat is None
            and _video_by_keyframes(plan, meta, key, rep, keyframes.get(key), limit, result)
        ):
            continue  # rendered bit for bit, and the video holds those frames at its keyframes
        if dat is None:  # a video whose every frame is needed after all
            dat = plan.frames.episode(ep, [key])[key]
        if rep is None:
            if key == STATE_FEATURE:
                continue  # the env has no get_state any more: nothing to compare the states with
            dataset_value = _value(dat[0], key in plan.image_keys) if len(dat) else None
            whole(key, dataset_value, "missing", f"the env's observation has no '{plan.features.get(key)}' any more")
            continue
        image = key in plan.image_keys
        rep = _as_dataset_layout(np.asarray(rep), dat, image)
        n = min(len(rep), len(dat))
        if rep.shape[1:] != dat.shape[1:]:
            whole(key, f"shape {dat.shape[1:]}", f"shape {rep.shape[1:]}", "the feature's shape changed")
            continue
        errors = frame_errors(rep[:n], dat[:n]) if video else step_errors(rep[:n], dat[:n])
        if video:
            result.video_errors[key] = errors.astype(np.float32)
            result.video_checked[key] = n
        if video and len(rep) == len(dat):
            recorded = meta.get(FRAMES_SHA256_COLUMN.format(key=key))
            if isinstance(recorded, str):  # push recorded the rendered frames' sha256: no second encoder pass
                result.video_exact[key], result.video_exact_by[key] = frames_sha256(rep) == recorded, "frames_sha256"
            else:
                result.video_exact[key] = _reencodes_exactly(rep, dat, plan.fps, plan.video_gops.get(key))
                result.video_exact_by[key] = "reencode"
        curves[key] = errors
        result.max_abs_diff[key] = float(errors.max()) if len(errors) else 0.0
        bad = np.flatnonzero(errors > limit) if dat.dtype.kind != "b" else np.flatnonzero(errors > 0)
        if len(bad):
            t = int(bad[0])
            note = ""
            if key == "next.done":
                if len(rep) > len(dat):
                    note = f"the dataset's episode ends after step {length - 1}; the env did not end it there"
                elif len(rep) < len(dat):
                    note = f"the env ended the episode after step {len(rep) - 1}; the dataset continues to step {length - 1}"
            result.divergences.append(
                Divergence(
                    ep,
                    seed,
                    t,
                    key,
                    plan.features.get(key),
                    float(errors[t]),
                    _element(rep[t], dat[t]),
                    _value(dat[t], image),
                    _value(rep[t], image),
                    note=note
                    or (
                        f"video frame: mean abs error above {limit:g} (the codec's tolerance, hub_envs.dataset.video)"
                        if video
                        else ""
                    ),
                )
            )
    result.divergences.sort(key=lambda d: (d.step, _feature_rank(d.feature)))
    if result.divergences and keep_curves:
        result.error_curve = {k: [float(x) for x in v] for k, v in curves.items()}
    return result


def _video_by_keyframes(
    plan: _Plan,
    meta: Mapping[str, Any],
    key: str,
    rep: np.ndarray,
    keyframes: tuple[np.ndarray, np.ndarray] | None,
    limit: float,
    result: EpisodeReplay,
) -> bool:
    """Whether video ``key`` of this episode is settled without decoding every frame: the rendered frames are the
    recorded ones bit for bit (their sha256 is the one push recorded) and each decoded keyframe is within ``limit``
    of its rendered frame, so the file holds them. Records the evidence in ``result`` when it is."""
    recorded = meta.get(FRAMES_SHA256_COLUMN.format(key=key))
    length = int(meta["length"])
    if keyframes is None or not isinstance(recorded, str) or not len(keyframes[0]):
        return False
    index, frames = keyframes
    rep = _as_dataset_layout(np.asarray(rep), frames, True)
    if len(rep) != length or rep.shape[1:] != frames.shape[1:] or frames_sha256(rep) != recorded:
        return False
    errors = frame_errors(rep[index], frames)
    if not (errors <= limit).all():
        return False  # the video does not hold the recorded frames there: every frame is compared, and named
    curve = np.full(length, np.nan, dtype=np.float32)  # the frames not decoded have no error to plot
    curve[index] = errors
    result.video_errors[key] = curve
    result.video_exact[key], result.video_exact_by[key] = True, "frames_sha256"
    result.video_checked[key] = len(index)
    result.max_abs_diff[key] = float(errors.max())
    return True


#: how the summary says a video was reproduced bit for bit, by ``video["bit_exact_by"]``
_BIT_EXACT_TEXT = {
    "frames_sha256": "; rendered bit for bit as recorded: the frames' sha256",
    "reencode": "; re-encoded, bit for bit",
}


def _reencodes_exactly(replay: np.ndarray, decoded: np.ndarray, fps: int, gop: int | None) -> bool:
    """Whether the replayed frames, encoded as push_env encoded the dataset's (GOP ``gop``, from its info.json),
    decode to exactly ``decoded``.

    The encoder is deterministic, so with the same encoder build identical frames give identical video: a
    bit-exact check on top of the tolerance (a different libsvtav1 build may give False with equal frames)."""
    if replay.dtype != np.uint8 or replay.ndim != 4 or replay.shape[-1] != 3:
        return False
    with tempfile.TemporaryDirectory(prefix="hub-envs-reencode-") as tmp:
        try:
            path, _, _ = encode_episode(np.ascontiguousarray(replay), Path(tmp) / "episode.mp4", fps, gop or LEROBOT_VIDEO_GOP)
            again = decode_episode(path, from_timestamp=0.0, length=len(replay), fps=fps, shape=replay.shape[1:], where="replay")
        except Exception:  # noqa: BLE001 - an extra check on top of the tolerance: it cannot say "bit for bit", that is all
            return False
    return bool(np.array_equal(again, decoded))


def _feature_rank(feature: str) -> int:
    # at one frame: observations (and state) come before the action's outcome
    return 2 if feature in NEXT_KEYS else 1 if feature == STATE_FEATURE else 0


def _first_transition(ep: EpisodeReplay) -> int:
    """The first step whose *transition* diverged: obs/state at frame t come from step t - 1."""
    steps = [d.step if d.feature in NEXT_KEYS else d.step - 1 for d in ep.divergences]
    return max(min(steps), -1)


def _reset_to(env: Any) -> Callable[[Any], Any] | None:
    return getattr(env.unwrapped, "reset_to", None)


def _localize_with_states(plan: _Plan, pos: int, env: Any, actions: np.ndarray, tolerance: float) -> dict[str, Any]:
    """robomimic playback: from every recorded state, one step; where does the one-step error start?"""
    meta = plan.metas[pos]
    ep, length = meta["episode_index"], int(meta["length"])
    data = plan.frames.episode(ep, keys=list(plan.features))
    states = plan.states[ep]
    raw = env.unwrapped
    env.reset(seed=plan.seeds[pos])
    get_state = getattr(raw, "get_state", None)
    errors = np.zeros(length)
    worst: list[str] = [""] * length
    for t in range(length):
        raw.reset_to(states[t])
        obs, reward, terminated, truncated, _info = raw.step(actions[t])
        errs = (
            {"next.reward": abs(float(np.float32(reward)) - float(data["next.reward"].reshape(-1)[t]))}
            if "next.reward" in data
            else {}
        )
        if t + 1 < length:
            flat = _flatten(obs)
            for key in plan.features:
                env_key = plan.features[key]
                if env_key is None or env_key not in flat:
                    continue
                rep = _as_dataset_layout(np.asarray(flat[env_key])[None], data[key][t + 1 : t + 2], key in plan.image_keys)
                if key in plan.video_keys:  # within the codec's tolerance counts as no error
                    err = float(frame_errors(rep, data[key][t + 1 : t + 2])[0])
                    errs[key] = err if err > VIDEO_TOLERANCE.max_mean_abs_error else 0.0
                else:
                    errs[key] = float(step_errors(rep, data[key][t + 1 : t + 2])[0])
            if get_state is not None:
                errs[STATE_FEATURE] = float(step_errors(np.asarray(get_state())[None], states[t + 1 : t + 2])[0])
            if "next.done" in data:
                errs["next.done"] = float(bool(terminated) != bool(data["next.done"].reshape(-1)[t]))
        key = max(errs, key=errs.get) if errs else ""
        errors[t], worst[t] = (errs[key], key) if key else (0.0, "")
    bad = np.flatnonzero(errors > tolerance)
    out: dict[str, Any] = {
        "method": "recorded states (reset_to(states[t]), step(actions[t]), compare with frame t+1)",
        "one_step_error": [float(x) for x in errors],
    }
    if len(bad):
        t = int(bad[0])
        out.update(
            first_step=t,
            feature=worst[t],
            max_abs_diff=float(errors[t]),
            steps_with_error=int(len(bad)),
            message=(
                f"playback diverged by {errors[t]:.6g} at step {t} ({worst[t]}): from the recorded state, "
                f"the env's step {t} no longer gives the recorded outcome, so its dynamics changed there "
                f"({len(bad)} of {length} steps differ one step ahead)."
            ),
        )
    else:
        out.update(
            first_step=None,
            message=(
                "from every recorded state, one step reproduces the data: the dynamics are unchanged, so the divergence "
                "comes from the reset or from state that get_state/reset_to do not cover"
            ),
        )
    return out


def _flatten(obs: Any) -> dict[str, Any]:
    return flatten_observation(obs)


def _localize_from_replay_state(
    make_env: Callable[[], Any], plan: _Plan, pos: int, ep: EpisodeReplay, actions: np.ndarray
) -> dict[str, Any]:
    """No recorded states: restore the replay's own state before the first diverging step in a fresh env."""
    j = _first_transition(ep)
    method = "replay state (reset_to(get_state()) before the first diverging step, in a fresh env)"
    if j < 0:
        return {
            "method": method,
            "first_step": None,
            "message": "the reset observation itself differs: env.reset(seed) changed, nothing to restore",
        }
    seed = plan.seeds[pos]
    first = run_episodes(make_env, [seed], max_steps=j + 2, policy=[actions[: j + 2]], record_states=True, progress=False)[0]
    if first.states is None or first.length <= j:
        return {"method": method, "first_step": None, "message": "the env records no state (get_state), cannot localize"}
    env = make_env()
    try:
        env.reset(seed=seed)
        raw = env.unwrapped
        raw.reset_to(first.states[j])
        obs, reward, *_ = raw.step(actions[j])
    finally:
        env.close()
    flat = _flatten(obs)
    same = float(reward) == float(first.rewards[j])
    if first.length > j + 1:
        for key, arr in first.observations.items():
            if key in flat and not np.array_equal(np.asarray(flat[key]), arr[j + 1], equal_nan=True):
                same = False
    if same:
        return {
            "method": method,
            "first_step": j,
            "message": (
                f"restoring the replay's own state before step {j} in a fresh env reproduces the diverging step: the "
                f"env's transition at step {j} differs from the one that recorded the data (all earlier observations matched)"
            ),
        }
    return {
        "method": method,
        "first_step": None,
        "message": (
            f"restoring the replay's state before step {j} does NOT reproduce the replay: the env is non-deterministic "
            f"or get_state/reset_to miss part of its state, so the divergence cannot be pinned to one transition"
        ),
    }


class _Done:
    """An already computed value with a future's ``result()``."""

    __slots__ = ("value",)

    def __init__(self, value: Any):
        self.value = value

    def result(self) -> Any:
        return self.value


class Replay:
    """One replay, in three steps, so its episodes can share a worker pool with other episodes.

    ``Replay(...)`` reads the dataset and builds a probe env; :attr:`seeds`, :attr:`policy`,
    :attr:`max_steps` and :attr:`record_states` are what to run through the rollout engine;
    :meth:`consume` compares the rollouts (in episode order) and :meth:`finish` localizes the
    diverged episodes and returns the :class:`ReplayResult`. :func:`replay_dataset` does all three.
    Use it as a context manager (or call :meth:`close`) so the probe env is closed.
    """

    def __init__(
        self,
        make_env: Callable[[], Any],
        dataset_root: str | Path,
        features_map: Mapping[str, str],
        *,
        tolerance: float = 0.0,
        episodes: list[int] | None = None,
        localize: bool = True,
    ):
        if tolerance < 0 or not np.isfinite(tolerance):
            raise ReproductionError(f"tolerance={tolerance!r}: pass a finite value >= 0 (0 means bit-exact).")
        self._t0 = time.perf_counter()
        self._seconds = 0.0
        self.make_env = make_env
        self.features_map = dict(features_map)
        self.tolerance = float(tolerance)
        self.localize = localize
        root = Path(dataset_root)
        self.plan = plan = _plan(root, features_map, episodes)
        self.probe = make_env()
        try:
            space = self.probe.action_space
            self.actions = [
                env_actions(a, space, f"{root} episode {m['episode_index']}") for a, m in zip(plan.actions, plan.metas)
            ]
            self.can_restore = _reset_to(self.probe) is not None
            self.record_states = plan.states is not None and getattr(self.probe.unwrapped, "get_state", None) is not None
            self.max_episode_steps = getattr(getattr(self.probe, "spec", None), "max_episode_steps", None)
        except BaseException:
            self.close()
            raise
        #: one extra action per episode: if the env does not end the episode where the data does, it shows
        self.policy = [np.concatenate([a, a[-1:]]) if len(a) else a for a in self.actions]
        self.seeds = list(plan.seeds)
        self.max_steps = max((len(a) for a in self.policy), default=1)
        self.results: list[EpisodeReplay] = []
        self.steps = 0
        self._keys = list(plan.features)
        self._reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hub-envs-replay-read")
        self._ahead: dict[int, Any] = {p: self._fetch(p) for p in range(min(2, len(plan.metas)))}
        self._seconds += time.perf_counter() - self._t0

    def __enter__(self) -> Replay:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        reader = getattr(self, "_reader", None)
        if reader is not None:
            reader.shutdown(wait=True, cancel_futures=True)
            self._reader = None
        if getattr(self, "plan", None) is not None:
            self.plan.frames.close()
        if getattr(self, "probe", None) is not None:
            try:
                self.probe.close()
            except Exception:  # noqa: BLE001
                pass
            self.probe = None

    def _fetch(self, pos: int) -> Any:
        """``(dataset frames, video keyframes)`` of episode ``pos``, a couple of episodes ahead: PNG images and videos
        without a recorded sha256 decoded in a thread; of a video whose rendered frames' sha256 is recorded only the
        keyframes, here (:func:`_compare_episode` decodes the rest only if the replay's frames turn out not to be the
        recorded ones)."""
        meta = self.plan.metas[pos]
        ep = meta["episode_index"]
        if not self.plan.image_keys:  # numeric columns are already in memory
            return _Done((self.plan.frames.episode(ep, self._keys), {}))
        by_keyframes = [k for k in self.plan.video_keys if isinstance(meta.get(FRAMES_SHA256_COLUMN.format(key=k)), str)]

        def read() -> tuple[dict[str, np.ndarray], dict[str, tuple[np.ndarray, np.ndarray]]]:
            frames = self.plan.frames
            data = frames.episode(ep, [k for k in self._keys if k not in by_keyframes])
            return data, {k: frames.video_keyframes(ep, k) for k in by_keyframes}

        if set(by_keyframes) == self.plan.image_keys:
            # keyframes only (a tenth of the frames): read here. In a thread, every packet's read gives the GIL up and
            # waits to get it back from the stepping env (the switch interval, 5 ms), so the env would wait for it
            return _Done(read())
        return self._reader.submit(read)

    def consume(self, rollout: Any) -> EpisodeReplay:
        """Compare the next episode's rollout (rollouts must come in episode order)."""
        t = time.perf_counter()
        pos = len(self.results)
        n = len(self.plan.metas)
        if pos + 2 < n:
            self._ahead[pos + 2] = self._fetch(pos + 2)
        data, keyframes = self._ahead.pop(pos).result()
        self.steps += rollout.length
        result = _compare_episode(
            self.plan, pos, rollout, data, self.features_map, self.tolerance, keep_curves=True, keyframes=keyframes
        )
        self.results.append(result)
        self._seconds += time.perf_counter() - t
        return result

    def finish(self, *, episodes_seconds: float = 0.0) -> ReplayResult:
        """Localize diverged episodes and return the result (``episodes_seconds``: time spent running the episodes)."""
        t = time.perf_counter()
        plan, results = self.plan, self.results
        if len(results) != len(plan.metas):
            raise ReproductionError(f"replay: {len(results)} of {len(plan.metas)} episodes were consumed before finish().")
        for ep in [e for e in results if not e.ok][MAX_LOCALIZED:]:
            ep.error_curve = {}  # per-step curves for the first few diverged episodes only: bounded report size
        if self.localize and self.can_restore:
            for pos, ep in [(p, e) for p, e in enumerate(results) if not e.ok][:MAX_LOCALIZED]:
                try:
                    if plan.states is not None and self.record_states:
                        ep.localization = _localize_with_states(plan, pos, self.probe, self.actions[pos], self.tolerance)
                    else:
                        ep.localization = _localize_from_replay_state(self.make_env, plan, pos, ep, self.actions[pos])
                except HubEnvsError:
                    raise
                except Exception as exc:  # noqa: BLE001 - localization is a diagnosis; report why it failed
                    ep.localization = {
                        "method": "reset_to",
                        "first_step": None,
                        "message": f"localization failed: {type(exc).__name__}: {exc}",
                    }
        self.close()
        if plan.states is None:
            states_note = "not recorded in the dataset" + (
                "; divergences localized with the replay's own get_state/reset_to" if self.can_restore else ""
            )
        elif not self.record_states:
            states_note = "recorded, but the env has no get_state/reset_to any more: not compared"
        else:
            states_note = "recorded: compared at every step as 'env_state'" + (
                "; divergences localized by state-restored playback" if self.can_restore else ""
            )
        features = dict(plan.features)
        video = None
        if plan.video_keys:
            worst = max((e.max_abs_diff.get(k, 0.0) for e in results for k in plan.video_keys), default=0.0)
            exact = all(e.video_exact.get(k, False) for e in results for k in plan.video_keys)
            per_frame = [e.video_errors[k] for e in results for k in plan.video_keys if k in e.video_errors]
            decoded = np.concatenate(per_frame) if per_frame else np.zeros(0, np.float32)
            decoded = decoded[~np.isnan(decoded)]
            by = sorted({how for e in results for how in e.video_exact_by.values()})
            checked = sum(e.video_checked.get(k, 0) for e in results for k in plan.video_keys)
            video = {
                "keys": sorted(plan.video_keys),
                "tolerance": VIDEO_TOLERANCE.to_dict(),
                "worst": worst,
                "mean": float(decoded.mean(dtype=np.float64)) if len(decoded) else 0.0,  # over the frames decoded
                "bit_exact": exact,
                "bit_exact_by": ", ".join(by) or None,
                "frames": sum(e.length for e in results) * len(plan.video_keys),
                "frames_checked": checked,  # decoded and compared within the tolerance
            }
        if plan.states is not None and self.record_states:
            features[STATE_FEATURE] = None
        self._seconds += time.perf_counter() - t
        return ReplayResult(
            episodes=results,
            tolerance=self.tolerance,
            features=features,
            skipped=plan.skipped,
            states=states_note,
            steps=self.steps,
            seconds=self._seconds + episodes_seconds,
            video=video,
        )


def replay_dataset(
    make_env: Callable[[], Any],
    dataset_root: str | Path,
    features_map: Mapping[str, str],
    *,
    tolerance: float = 0.0,
    workers: int = 1,
    episodes: list[int] | None = None,
    localize: bool = True,
    progress: bool = True,
) -> ReplayResult:
    """Replay every episode of the dataset at ``dataset_root`` in envs from ``make_env`` and compare.

    Args:
        make_env: builds the env (e.g. ``loaded.make``); called once per worker process.
        dataset_root: a LeRobot v3 dataset written by hub-envs (seeds recorded).
        features_map: the EnvConfig's ``features_map`` (env key -> dataset key).
        tolerance: largest absolute difference accepted per value (0: bit-exact). Booleans are exact.
        workers: processes for the open-loop replay; the result does not depend on it.
        episodes: replay only these episode indices (default: all).
        localize: localize diverged episodes with ``reset_to`` (at most 3 episodes).
        progress: show a progress bar.

    Returns:
        The per-episode comparisons, the divergences (localized when asked) and the frame counts.

    Raises:
        ReproductionError: the dataset cannot be replayed (no seeds, no actions, action space changed).
        EnvCodeError: the env raised while replaying.
    """
    with Replay(make_env, dataset_root, features_map, tolerance=tolerance, episodes=episodes, localize=localize) as replay:
        t = time.perf_counter()
        consumed = 0.0
        for rollout in iter_episodes(
            make_env,
            replay.seeds,
            max_steps=replay.max_steps,
            policy=replay.policy,
            record_states=replay.record_states,
            workers=workers,
            progress=progress,
            desc=f"Replaying {len(replay.seeds)} episodes",
        ):
            c = time.perf_counter()
            replay.consume(rollout)
            consumed += time.perf_counter() - c
        return replay.finish(episodes_seconds=time.perf_counter() - t - consumed)
