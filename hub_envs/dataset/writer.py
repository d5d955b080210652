"""Write LeRobot v3.0 datasets of env rollouts, fast and byte-deterministically.

One concept: the bundled dataset is a plain LeRobot v3.0 folder that
``lerobot.datasets.lerobot_dataset.LeRobotDataset(repo_id, root=folder)`` loads, written directly
with pyarrow instead of LeRobot's ``add_frame``/``save_episode`` path (which stages every frame in
Python lists, writes PNG files to disk, re-reads them through ``datasets.map`` and rewrites
metadata after every episode). The files are those LeRobot writes for a dataset without videos::

    meta/info.json                               codebase_version "v3.0", features, totals, paths
    meta/stats.json                              global stats per feature (min/max/mean/std/count/q01..q99)
    meta/tasks.parquet                           pandas frame: index = task string, column task_index
    meta/episodes/chunk-000/file-000.parquet     one row per episode: index, tasks, length, data file,
                                                 dataset_from/to_index, stats/<key>/<stat>, meta file, seed
    data/chunk-000/file-000.parquet              one row per frame, schema of datasets.Features (the
                                                 "huggingface" schema metadata included)

Video features (dtype ``"video"``, LeRobot's default for cameras) are MP4 files
``videos/<key>/chunk-000/file-000.mp4`` encoded by LeRobot's own encoder (:mod:`hub_envs.dataset.video`),
each episode's span in the episodes metadata (``videos/<key>/from_timestamp``...) and the stream's
``info`` in ``info.json``, as LeRobot's ``save_episode`` writes them. Image features use dtype ``"image"``: each frame is stored inside the data parquet as the
``datasets.Image`` struct ``{bytes: PNG, path: "frame-000012.png"}``, exactly the layout LeRobot's
``embed_images`` produces, so LeRobot decodes them with PIL to the same tensors. PNGs are written
by a small vectorised encoder (filter "Up" + zlib level 1) instead of PIL at level 6: same pixels,
~6x faster, in a helper process while the next episodes are made (:mod:`hub_envs.dataset.png_process`). Differences from LeRobot's writer, none visible to its reader:

* Stats are exact (:mod:`hub_envs.dataset.stats`; ``meta/hub_envs.json["stats"]`` says how they differ).
  Global stats aggregate the episode stats with LeRobot's formula (1000 episodes at a time).
* Several episodes share one parquet row group; files roll over by the same size rule, measured on
  the Arrow bytes written rather than the file size on disk.
* Extra: a ``seed`` column in the episodes metadata (and ``frames_sha256/<key>`` per video feature: the
  rendered frames' sha256, which replay checks) and ``meta/hub_envs.json`` =
  ``{"seeds": [...], "stats": STATS_NOTE, **extra_info}`` (a file LeRobot does not read; ``info.json`` holds
  exactly the keys LeRobot's own writer puts there, so LeRobot >= 0.5 logs no "Unknown fields").
* Byte-deterministic: no timestamps or random fingerprints in any file, fixed writer options.

Example:
    >>> import tempfile, numpy as np
    >>> from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset
    >>> from hub_envs.dataset.reader import read_episode_frames
    >>> features = {"observation.state": {"dtype": "float32", "shape": [2], "names": ["x", "v"]},
    ...             "action": {"dtype": "float32", "shape": [1], "names": ["u"]}}
    >>> eps = [EpisodeFrames(i, seed=i, frames={"observation.state": np.zeros((5, 2), np.float32),
    ...                                         "action": np.ones((5, 1), np.float32)}) for i in range(2)]
    >>> root = tempfile.mkdtemp() + "/ds"
    >>> s = write_lerobot_dataset(root, repo_id="me/ds", fps=10, features=features, episodes=eps,
    ...                           task="demo", progress=False)
    >>> s.episodes, s.frames, s.seeds, read_episode_frames(root, 1)["action"].shape
    (2, 10, (0, 1), (5, 1))
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import uuid
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from huggingface_hub.utils import tqdm

from hub_envs._compat import lerobot_video_info, tasks_index_name
from hub_envs.dataset import png_process
from hub_envs.dataset.codec import PNG_CHANNELS, encode_png
from hub_envs.dataset.layout import (
    CODEBASE_VERSION,
    DATA_PATH,
    DEFAULT_CHUNK_SIZE,
    DEFAULT_DATA_FILE_SIZE_IN_MB,
    DEFAULT_FEATURES,
    DEFAULT_VIDEO_FILE_SIZE_IN_MB,
    EPISODES_PATH,
    FRAMES_SHA256_COLUMN,
    HUB_ENVS_META_PATH,
    INFO_PATH,
    NEXT_FEATURES,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_PATH,
)
from hub_envs.dataset.reader import dataset_fingerprint
from hub_envs.dataset.stats import STATS_NOTE, aggregate_stats, image_stats, vector_stats_many
from hub_envs.dataset.video import DEFAULT_VIDEO_GOP, check_video_gop, encode_episode, frames_sha256, join_videos
from hub_envs.errors import ConfigError, DatasetError, HubEnvsError

_NUMERIC_DTYPES = {
    "bool",
    "float16",
    "float32",
    "float64",
    "int8",
    "int16",
    "int32",
    "int64",
    "uint8",
    "uint16",
    "uint32",
    "uint64",
}
__all__ = ["EpisodeFrames", "DatasetSummary", "write_lerobot_dataset", "rollout_to_frames", "dataset_features_from_config"]

# parquet writer options, fixed so the same rows give the same bytes
_PARQUET_OPTS = dict(compression="snappy", use_dictionary=True, write_statistics=True, version="2.6")
_FLUSH_ROWS = 65536
_FLUSH_BYTES = 32 * 2**20
_META_FLUSH_ROWS = 1000


# --- inputs -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class EpisodeFrames:
    """One episode to write: ``frames[lerobot_key]`` is a ``(T, *shape)`` array per feature.

    ``index`` must count 0, 1, 2, ... in the order episodes are given; ``seed`` is the reset seed
    (recorded in the metadata; ``None`` if unknown). A ``"timestamp"`` array may be given to
    override the default ``frame_index / fps``. ``task_index`` is the episode's task in a dataset of several
    (``write_lerobot_dataset(task=[...])``): every frame's ``task_index``.
    """

    index: int
    seed: int | None
    frames: dict[str, np.ndarray]
    task_index: int = 0

    @property
    def length(self) -> int:
        return int(len(next(iter(self.frames.values())))) if self.frames else 0

    @classmethod
    def from_rollout(cls, rollout: Any, features_map: Mapping[str, str], keys: Iterable[str] | None = None) -> EpisodeFrames:
        """Build from a :class:`hub_envs.harness.rollout.EpisodeRollout` via :func:`rollout_to_frames`."""
        return cls(rollout.index, rollout.seed, rollout_to_frames(rollout, features_map, keys=keys))


def rollout_to_frames(
    rollout: Any, features_map: Mapping[str, str], *, keys: Iterable[str] | None = None
) -> dict[str, np.ndarray]:
    """Rename a rollout's env-side arrays to LeRobot keys and add ``next.reward/done/success``.

    ``features_map`` is LeRobot's ``EnvConfig.features_map`` (env key → dataset key), e.g.
    ``{"action": "action", "agent_pos": "observation.state", "pixels": "observation.image"}``.
    Observation keys absent from the map are not recorded. The action goes to
    ``features_map.get("action", "action")``; ``next.done`` is ``terminated | truncated``.
    ``keys`` (optional) keeps only those dataset keys.

    >>> from types import SimpleNamespace as NS
    >>> r = NS(observations={"agent_pos": np.zeros((2, 3)), "extra": np.zeros(2)}, actions=np.zeros((2, 1)),
    ...        rewards=np.array([1.0, 2.0]), terminated=np.array([False, False]),
    ...        truncated=np.array([False, True]), is_success=np.array([False, False]))
    >>> f = rollout_to_frames(r, {"agent_pos": "observation.state", "action": "action"})
    >>> sorted(f), f["next.done"].tolist()
    (['action', 'next.done', 'next.reward', 'next.success', 'observation.state'], [False, True])
    """
    out: dict[str, np.ndarray] = {}
    for env_key, arr in rollout.observations.items():
        if env_key in features_map:
            out[features_map[env_key]] = arr
    out[features_map.get("action", "action")] = rollout.actions
    out["next.reward"] = np.asarray(rollout.rewards, dtype=np.float32)
    out["next.done"] = np.asarray(rollout.terminated, dtype=bool) | np.asarray(rollout.truncated, dtype=bool)
    out["next.success"] = np.asarray(rollout.is_success, dtype=bool)
    if keys is not None:
        wanted = set(keys)
        out = {k: v for k, v in out.items() if k in wanted}
    return out


def dataset_features_from_config(
    cfg: Any,
    *,
    names: Mapping[str, list[str]] | None = None,
    action: tuple[tuple[int, ...], str] | None = None,
    video: bool = False,
) -> dict[str, dict]:
    """info.json-style features for a LeRobot ``EnvConfig`` (its ``features`` and ``features_map``).

    VISUAL features become ``{"dtype": "image", "shape": [H, W, C], "names": ["height", "width",
    "channels"]}`` (channel-first shapes are turned channel-last; dtype ``"video"`` with ``video=True``, for
    3-channel features); STATE/ACTION/ENV features become
    float32 with ``names`` (from ``names[dataset_key]`` or ``<env_key>_<i>`` for 1-D shapes).
    ``next.reward`` (float32), ``next.done`` and ``next.success`` (bool) are appended. ``action`` is the
    ``(shape, dtype)`` the env's action space is stored as (:func:`hub_envs.harness.actions.stored_action`:
    int64 ``(1,)`` for a ``Discrete``), when it is known.

    >>> from types import SimpleNamespace as NS
    >>> cfg = NS(features={"action": NS(type="ACTION", shape=(1,)), "pixels": NS(type="VISUAL", shape=(3, 8, 8))},
    ...          features_map={"action": "action", "pixels": "observation.image"})
    >>> f = dataset_features_from_config(cfg)
    >>> f["action"], f["observation.image"]["shape"], list(f)[-1]
    ({'dtype': 'float32', 'shape': [1], 'names': ['action_0']}, [8, 8, 3], 'next.success')
    """
    names = dict(names or {})
    out: dict[str, dict] = {}
    for env_key, ft in cfg.features.items():
        if env_key not in cfg.features_map:
            raise ConfigError(
                f"EnvConfig feature '{env_key}' has no entry in features_map. Add "
                f"features_map['{env_key}'] = '<dataset key>' (e.g. 'observation.state')."
            )
        key = cfg.features_map[env_key]
        ftype = str(getattr(ft.type, "value", ft.type)).upper()
        shape = [int(d) for d in ft.shape]
        if ftype.endswith("VISUAL"):
            if len(shape) != 3:
                raise ConfigError(f"Visual feature '{env_key}' has shape {tuple(shape)}; images need 3 dimensions (H, W, C).")
            if shape[0] in (1, 3, 4) and shape[2] not in (1, 3, 4):
                shape = [shape[1], shape[2], shape[0]]
            dtype = "video" if video and shape[2] == 3 else "image"
            out[key] = {"dtype": dtype, "shape": shape, "names": ["height", "width", "channels"]}
        else:
            feature_names = names.get(key)
            if feature_names is None and len(shape) == 1:
                feature_names = [f"{env_key.replace('/', '_')}_{i}" for i in range(shape[0])]
            dtype = "float32"
            if ftype.endswith("ACTION") and action is not None:
                shape, dtype = list(action[0]), action[1]
                if feature_names is None and len(shape) == 1:
                    feature_names = [f"{env_key.replace('/', '_')}_{i}" for i in range(shape[0])]
            out[key] = {"dtype": dtype, "shape": shape, "names": feature_names}
    for key, ft in NEXT_FEATURES.items():
        out.setdefault(key, {**ft, "shape": list(ft["shape"])})
    return out


# --- outputs ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class DatasetSummary:
    """What :func:`write_lerobot_dataset` wrote. ``fingerprint`` is :func:`dataset_fingerprint` of the folder."""

    root: Path
    repo_id: str
    episodes: int
    frames: int
    fps: int
    features: dict = field(hash=False)
    episode_lengths: tuple[int, ...]
    seeds: tuple[int | None, ...]
    return_mean: float | None
    return_std: float | None
    return_min: float | None
    return_max: float | None
    success_rate: float | None
    fingerprint: str

    def to_dict(self) -> dict:
        d = asdict(self)
        d["root"] = str(self.root)
        d["episode_lengths"] = list(self.episode_lengths)
        d["seeds"] = list(self.seeds)
        return d


# --- feature handling -------------------------------------------------------------------------


def _normalize_features(features: Mapping[str, Mapping]) -> dict[str, dict]:
    if not isinstance(features, Mapping) or not features:
        raise ConfigError("features must be a non-empty dict {dataset_key: {'dtype', 'shape', 'names'}}.")
    out: dict[str, dict] = {}
    for key, ft in features.items():
        if not isinstance(key, str) or "/" in key or not key:
            raise ConfigError(f"Feature name {key!r} is invalid: LeRobot feature names are non-empty and contain no '/'.")
        if key in DEFAULT_FEATURES:
            raise ConfigError(f"Feature '{key}' is reserved: LeRobot adds {sorted(DEFAULT_FEATURES)} itself. Remove it.")
        if not isinstance(ft, Mapping) or "dtype" not in ft or "shape" not in ft:
            raise ConfigError(f"Feature '{key}' must be a dict with 'dtype', 'shape' and 'names'; got {ft!r}.")
        dtype = ft["dtype"]
        shape = [int(d) for d in ft["shape"]]
        if dtype == "video":
            if len(shape) != 3 or shape[2] != 3:
                raise ConfigError(f"Video feature '{key}' has shape {shape}; use [height, width, 3] (RGB).")
        elif dtype == "image":
            if len(shape) != 3 or shape[2] not in PNG_CHANNELS:
                raise ConfigError(f"Image feature '{key}' has shape {shape}; use [height, width, channels] with 1-4 channels.")
        elif dtype not in _NUMERIC_DTYPES:
            raise ConfigError(f"Feature '{key}' has dtype {dtype!r}; supported: 'image', 'video' and {sorted(_NUMERIC_DTYPES)}.")
        if not shape or any(d < 1 for d in shape):
            raise ConfigError(f"Feature '{key}' has shape {shape}; use a non-empty list of positive sizes ([1] for scalars).")
        out[key] = {**{k: v for k, v in ft.items() if k != "info"}, "dtype": dtype, "shape": shape, "names": ft.get("names")}
    for key, ft in DEFAULT_FEATURES.items():
        out[key] = {**ft, "shape": list(ft["shape"])}
    return out


def _hf_features(features: dict[str, dict]):
    """lerobot.datasets.utils.get_hf_features_from_features."""
    import datasets  # heavy: datasets (pyarrow, pandas)

    hf = {}
    for key, ft in features.items():
        shape = tuple(ft["shape"])
        if ft["dtype"] == "video":  # stored as MP4 files beside the data, not as a column
            continue
        if ft["dtype"] == "image":
            hf[key] = datasets.Image()
        elif shape == (1,):
            hf[key] = datasets.Value(dtype=ft["dtype"])
        elif len(shape) == 1:
            hf[key] = datasets.Sequence(length=shape[0], feature=datasets.Value(dtype=ft["dtype"]))
        elif 2 <= len(shape) <= 5:
            cls = getattr(datasets, f"Array{len(shape)}D")
            hf[key] = cls(shape=shape, dtype=ft["dtype"])
        else:
            raise ConfigError(f"Feature '{key}' has {len(shape)} dimensions; LeRobot supports 1 to 5.")
    return datasets.Features(hf)


def _nested_list_array(flat: np.ndarray, shape: tuple[int, ...], n_rows: int, storage_type):
    """Storage for datasets' ArrayND extension: nested variable-size lists of ``flat`` values."""
    import pyarrow as pa  # heavy: pyarrow

    arr = pa.array(flat.reshape(-1))
    sizes = [n_rows] + list(shape)
    for depth in range(len(shape), 0, -1):
        n_lists = int(np.prod(sizes[:depth]))
        arr = pa.ListArray.from_arrays(
            pa.array(np.arange(0, n_lists * shape[depth - 1] + 1, shape[depth - 1], dtype=np.int32)), arr
        )
    return arr.cast(storage_type)


# --- the writer -------------------------------------------------------------------------------


@dataclass
class _Episode:
    index: int
    seed: int | None
    length: int
    columns: dict[str, np.ndarray]  # numeric columns, cast; images as uint8 (T, H, W, C)
    task_index: int = 0
    pngs: dict[str, list[bytes]] = field(default_factory=dict)
    videos: dict[str, tuple[Path, float, int]] = field(default_factory=dict)  # key -> (mp4, duration s, bytes)
    digests: dict[str, str] = field(default_factory=dict)  # video key -> frames_sha256 of the frames before encoding
    stats: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    table: Any = None  # the rows, as an Arrow table of the data files' schema (made by _Writer.encode)


@functools.lru_cache(maxsize=8)
def _frame_paths(n: int) -> Any:
    """The ``path`` field of an episode's image structs (LeRobot's ``embed_images`` names): the same for every
    episode of ``n`` frames, so made once."""
    import pyarrow as pa

    return pa.array([f"frame-{i:06d}.png" for i in range(n)], type=pa.string())


class _Writer:
    def __init__(
        self,
        tmp: Path,
        features: dict[str, dict],
        fps: int,
        task: str | tuple[str, ...],
        chunks_size: int,
        file_mb: float,
        video_file_mb: float = DEFAULT_VIDEO_FILE_SIZE_IN_MB,
        video_gop: int | None = None,
    ):
        import pyarrow as pa  # heavy: pyarrow

        self.tmp = tmp
        self.features = features
        self.fps = fps
        self.tasks = (task,) if isinstance(task, str) else tuple(task)  # by task_index
        self.chunks_size = chunks_size
        self.file_mb = file_mb
        self.file_bytes_limit = file_mb * 2**20
        self.n_pending = 0  # episodes / frames accepted by prepare() (ahead of write() when pipelined)
        self.frames_pending = 0
        self.hf = _hf_features(features)
        self.schema = self.hf.arrow_schema  # carries the "huggingface" features metadata, no fingerprint
        self.image_keys = [k for k, ft in features.items() if ft["dtype"] == "image"]
        self.video_keys = [k for k, ft in features.items() if ft["dtype"] == "video"]
        # video files: per key, the file being filled and the episode MP4s it will join
        self.video_file_mb = video_file_mb
        self.video_gop = DEFAULT_VIDEO_GOP if video_gop is None else video_gop
        self.video_pos = {k: (0, 0) for k in self.video_keys}
        self.video_parts: dict[str, list[Path]] = {k: [] for k in self.video_keys}
        self.video_bytes = dict.fromkeys(self.video_keys, 0)
        self.video_seconds = dict.fromkeys(self.video_keys, 0.0)
        self.pa = pa
        # data files
        self.data_pos = (0, 0)
        self.data_writer = None
        self.data_file_bytes = 0
        self.data_file_rows = 0
        self.buffer: list = []
        self.buffer_rows = 0
        self.buffer_bytes = 0
        # episode metadata files
        self.meta_pos = (0, 0)
        self.meta_writer = None
        self.meta_schema = None
        self.meta_file_bytes = 0
        self.meta_rows: list[dict] = []
        # totals
        self.total_frames = 0
        self.n_episodes = 0
        self.stats: dict[str, dict[str, np.ndarray]] | None = None  # global stats of folded episodes
        self.pending_stats: list[dict[str, dict[str, np.ndarray]]] = []  # episode stats not folded yet
        self.seeds: list[int | None] = []
        self.lengths: list[int] = []
        self.returns: list[float] = []
        self.successes: list[bool] = []

    # -- per episode, maybe in a worker thread --

    def prepare(self, ep: Any) -> _Episode:
        """Validate and cast one EpisodeFrames; add LeRobot's default columns."""
        if not isinstance(ep, EpisodeFrames):
            raise DatasetError(f"episodes must yield EpisodeFrames, got {type(ep).__name__} at position {self.n_pending}.")
        where = f"episode {ep.index}"
        if ep.index != self.n_pending:
            raise DatasetError(
                f"{where} arrived in position {self.n_pending}: EpisodeFrames.index must count 0, 1, 2, ... in order."
            )
        frames = dict(ep.frames)
        timestamp = frames.pop("timestamp", None)
        expected = [k for k in self.features if k not in DEFAULT_FEATURES]
        missing = [k for k in expected if k not in frames]
        extra = [k for k in frames if k not in self.features]
        if missing or extra:
            raise DatasetError(
                f"{where}: frames keys do not match features (missing {missing}, not in features {extra}). "
                "Give exactly one array per declared feature."
            )
        cols: dict[str, np.ndarray] = {}
        length = None
        for key in expected:
            ft = self.features[key]
            arr = np.asarray(frames[key])
            if length is None:
                length = arr.shape[0] if arr.ndim else 0
            shape = tuple(ft["shape"])
            if ft["dtype"] in ("image", "video"):
                arr = self._image(where, key, arr, shape)
            else:
                if arr.shape == (length,) and shape == (1,):
                    arr = arr.reshape(length, 1)
                if arr.shape != (length, *shape):
                    raise DatasetError(
                        f"{where}: '{key}' has shape {arr.shape}, expected {(length, *shape)} (T, *feature shape)."
                    )
                dtype = np.dtype(ft["dtype"])
                if arr.dtype != dtype:
                    if not np.can_cast(arr.dtype, dtype, "same_kind") and not (arr.dtype == bool):
                        raise DatasetError(
                            f"{where}: '{key}' has dtype {arr.dtype}, which cannot be stored as {dtype} without losing meaning."
                        )
                    arr = arr.astype(dtype)
                if dtype.kind == "f" and not np.isfinite(arr).all():
                    bad = int(np.flatnonzero(~np.isfinite(arr.reshape(length, -1)).all(axis=1))[0])
                    raise DatasetError(f"{where}: '{key}' is NaN or inf at frame {bad}. Only finite values can be written.")
            if arr.shape[0] != length:
                raise DatasetError(
                    f"{where}: '{key}' has {arr.shape[0]} frames but '{expected[0]}' has {length}; all arrays need the same length."
                )
            cols[key] = arr
        if not length:
            raise DatasetError(f"{where} has no frames. Every episode needs at least one frame.")
        start = self.frames_pending
        frame_index = np.arange(length, dtype=np.int64)
        if timestamp is None:
            ts64 = frame_index / self.fps
        else:
            ts64 = np.asarray(timestamp, dtype=np.float64).reshape(-1)
            if ts64.shape != (length,):
                raise DatasetError(f"{where}: 'timestamp' has shape {np.shape(timestamp)}, expected ({length},).")
        cols["timestamp"] = ts64  # stats over float64 values like LeRobot; stored as float32
        cols["frame_index"] = frame_index
        cols["episode_index"] = np.full(length, ep.index, dtype=np.int64)
        cols["index"] = np.arange(start, start + length, dtype=np.int64)
        task_index = int(getattr(ep, "task_index", 0))
        if not 0 <= task_index < len(self.tasks):
            raise DatasetError(f"{where}: task_index {task_index} names no task; the dataset has {len(self.tasks)}.")
        cols["task_index"] = np.full(length, task_index, dtype=np.int64)
        seed = None if ep.seed is None else int(ep.seed)
        self.n_pending += 1
        self.frames_pending += length
        return _Episode(ep.index, seed, int(length), cols, task_index=task_index)

    def _image(self, where: str, key: str, arr: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        h, w, c = shape
        if arr.ndim == 4 and arr.shape[1:] == (c, h, w) and arr.shape[1:] != (h, w, c):
            arr = arr.transpose(0, 2, 3, 1)
        if arr.ndim != 4 or arr.shape[1:] != (h, w, c):
            raise DatasetError(
                f"{where}: image '{key}' has shape {arr.shape}, expected (T, {h}, {w}, {c}) or (T, {c}, {h}, {w})."
            )
        if arr.dtype != np.uint8:
            if arr.dtype.kind != "f":
                raise DatasetError(f"{where}: image '{key}' has dtype {arr.dtype}; give uint8 in [0, 255] or floats in [0, 1].")
            if not np.isfinite(arr).all() or arr.min() < 0.0 or arr.max() > 1.0:
                raise DatasetError(f"{where}: float image '{key}' has values outside [0, 1].")
            arr = (arr * 255).astype(np.uint8)  # LeRobot's image_array_to_pil_image conversion
        return np.ascontiguousarray(arr)

    def encode(self, ep: _Episode, images: list[tuple[list[bytes], dict[str, np.ndarray]]] | None = None) -> _Episode:
        """PNG-encode images, video-encode video features (one MP4 per episode and key, joined into the
        dataset's files by :meth:`write`) and compute episode stats (thread-safe, no shared state). ``images``: the
        image keys' PNGs and stats, made elsewhere (:mod:`hub_envs.dataset.png_process`), in ``image_keys`` order."""
        for n, key in enumerate(self.image_keys):
            if images is None:
                ep.pngs[key] = encode_png(ep.columns[key])
            else:
                ep.pngs[key], ep.stats[key] = images[n]
        for key in self.video_keys:
            part = self.tmp / ".video-parts" / key / f"episode-{ep.index:06d}.mp4"
            ep.videos[key] = encode_episode(ep.columns[key], part, self.fps, self.video_gop)
            ep.digests[key] = frames_sha256(ep.columns[key])  # what replay checks the rendered frames against
        numeric = [key for key, ft in self.features.items() if ft["dtype"] not in ("image", "video")]
        for key, stats in zip(numeric, vector_stats_many([ep.columns[key] for key in numeric]), strict=True):
            ep.stats[key] = stats
        for key in self.image_keys + self.video_keys:
            if key not in ep.stats:  # made with the PNGs elsewhere
                ep.stats[key] = image_stats(ep.columns[key])
        ep.stats = {key: ep.stats[key] for key in self.features}  # in the features' order, as the metadata columns are
        ep.table = self._table(ep)
        return ep

    def _table(self, ep: _Episode) -> Any:
        """The episode's rows as an Arrow table of the data files' schema (thread-safe, no shared state)."""
        pa = self.pa
        n = ep.length
        arrays = []
        for key, ft in self.features.items():
            if ft["dtype"] == "video":
                continue
            col = ep.columns[key]
            typ = self.schema.field(key).type
            if ft["dtype"] == "image":
                arrays.append(
                    pa.StructArray.from_arrays([pa.array(ep.pngs[key], type=pa.binary()), _frame_paths(n)], fields=list(typ))
                )
            elif key == "timestamp":
                arrays.append(pa.array(col.astype(np.float32)))
            elif tuple(ft["shape"]) == (1,):
                arrays.append(pa.array(col.reshape(n)))
            elif len(ft["shape"]) == 1:
                arrays.append(pa.FixedSizeListArray.from_arrays(pa.array(col.reshape(-1)), ft["shape"][0]).cast(typ))
            else:
                storage = _nested_list_array(col, tuple(ft["shape"]), n, typ.storage_type)
                arrays.append(pa.ExtensionArray.from_storage(typ, storage))
        return pa.Table.from_arrays(arrays, schema=self.schema)

    # -- sequential part: write --

    def write(self, ep: _Episode) -> None:
        n = ep.length
        table = ep.table
        nbytes = table.nbytes
        if self.data_file_rows > 0 and self.data_file_bytes + nbytes >= self.file_bytes_limit:
            self._close_data_file()
            self.data_pos = _next_file(*self.data_pos, self.chunks_size)
        chunk, file = self.data_pos
        self.buffer.append(table)
        self.buffer_rows += n
        self.buffer_bytes += nbytes
        self.data_file_bytes += nbytes
        self.data_file_rows += n
        if self.buffer_rows >= _FLUSH_ROWS or self.buffer_bytes >= _FLUSH_BYTES:
            self._flush_data()

        row = {
            "episode_index": ep.index,
            "tasks": [self.tasks[ep.task_index]],
            "length": n,
            "data/chunk_index": chunk,
            "data/file_index": file,
            "dataset_from_index": self.total_frames,
            "dataset_to_index": self.total_frames + n,
        }
        for key in self.video_keys:
            row.update(self._place_video(key, ep.videos[key]))
            row[FRAMES_SHA256_COLUMN.format(key=key)] = ep.digests[key]
        for key in self.features:
            for stat, value in ep.stats[key].items():
                row[f"stats/{key}/{stat}"] = value.tolist()
        self.seeds.append(ep.seed)  # before the row: a full batch of rows is flushed with its seeds at once
        self._add_meta_row(row)

        self.pending_stats.append(ep.stats)
        if len(self.pending_stats) >= _META_FLUSH_ROWS:
            self._fold_stats()
        self.total_frames += n
        self.n_episodes += 1
        self.lengths.append(n)
        if "next.reward" in ep.columns:
            self.returns.append(float(ep.columns["next.reward"].sum(dtype=np.float64)))
        if "next.success" in ep.columns:
            self.successes.append(bool(ep.columns["next.success"].any()))

    def _place_video(self, key: str, part: tuple[Path, float, int]) -> dict[str, Any]:
        """Put one episode's MP4 into the key's current file (a new file when it would reach the size
        limit: LeRobot's rule), and return its episodes-metadata columns."""
        path, duration, size = part
        if self.video_parts[key] and self.video_bytes[key] + size >= self.video_file_mb * 2**20:
            self._close_video_file(key)
            self.video_pos[key] = _next_file(*self.video_pos[key], self.chunks_size)
        start = self.video_seconds[key]
        self.video_parts[key].append(path)
        self.video_bytes[key] += size
        self.video_seconds[key] = start + duration
        chunk, file = self.video_pos[key]
        return {
            f"videos/{key}/chunk_index": chunk,
            f"videos/{key}/file_index": file,
            f"videos/{key}/from_timestamp": start,
            f"videos/{key}/to_timestamp": start + duration,
        }

    def _close_video_file(self, key: str) -> None:
        if self.video_parts[key]:
            chunk, file = self.video_pos[key]
            join_videos(self.video_parts[key], self.tmp / VIDEO_PATH.format(video_key=key, chunk_index=chunk, file_index=file))
        self.video_parts[key], self.video_bytes[key], self.video_seconds[key] = [], 0, 0.0

    def _fold_stats(self) -> None:
        """Aggregate the pending episode stats (in batches, so memory stays bounded) into self.stats."""
        if not self.pending_stats:
            return
        parts = ([self.stats] if self.stats is not None else []) + self.pending_stats
        self.stats = {k: parts[0][k] if len(parts) == 1 else aggregate_stats([p[k] for p in parts]) for k in self.features}
        self.pending_stats = []

    def _flush_data(self) -> None:
        if not self.buffer:
            return
        import pyarrow.parquet as pq  # heavy: pyarrow

        table = self.pa.concat_tables(self.buffer)
        if self.data_writer is None:
            path = self.tmp / DATA_PATH.format(chunk_index=self.data_pos[0], file_index=self.data_pos[1])
            path.parent.mkdir(parents=True, exist_ok=True)
            self.data_writer = pq.ParquetWriter(path, self.schema, **_PARQUET_OPTS)
        self.data_writer.write_table(table, row_group_size=table.num_rows)
        self.buffer, self.buffer_rows, self.buffer_bytes = [], 0, 0

    def _close_data_file(self) -> None:
        self._flush_data()
        if self.data_writer is not None:
            self.data_writer.close()
            self.data_writer = None
        self.data_file_bytes = 0
        self.data_file_rows = 0

    def _add_meta_row(self, row: dict) -> None:
        self.meta_rows.append(row)
        if len(self.meta_rows) >= _META_FLUSH_ROWS:
            self._flush_meta()

    def _flush_meta(self) -> None:
        if not self.meta_rows:
            return
        import pyarrow.parquet as pq  # heavy: pyarrow

        pa = self.pa
        names = list(self.meta_rows[0])
        columns = {name: [r[name] for r in self.meta_rows] for name in names}
        seeds = self.seeds[len(self.seeds) - len(self.meta_rows) :]
        table = pa.Table.from_pydict(columns)
        if self.meta_schema is not None:
            table = table.select(self.meta_schema.names[:-3]).cast(pa.schema(list(self.meta_schema)[:-3]))
        if self.meta_writer is not None and self.meta_file_bytes + table.nbytes >= self.file_bytes_limit:
            self.meta_writer.close()
            self.meta_writer = None
            self.meta_file_bytes = 0
            self.meta_pos = _next_file(*self.meta_pos, self.chunks_size)
        n = table.num_rows
        table = table.append_column("meta/episodes/chunk_index", pa.array(np.full(n, self.meta_pos[0], dtype=np.int64)))
        table = table.append_column("meta/episodes/file_index", pa.array(np.full(n, self.meta_pos[1], dtype=np.int64)))
        table = table.append_column("seed", pa.array(seeds, type=pa.int64()))
        if self.meta_schema is None:
            self.meta_schema = table.schema
        if self.meta_writer is None:
            path = self.tmp / EPISODES_PATH.format(chunk_index=self.meta_pos[0], file_index=self.meta_pos[1])
            path.parent.mkdir(parents=True, exist_ok=True)
            self.meta_writer = pq.ParquetWriter(path, self.meta_schema, **_PARQUET_OPTS)
        self.meta_writer.write_table(table, row_group_size=n)
        self.meta_file_bytes += table.nbytes
        self.meta_rows = []

    def finish(self, *, robot_type: str | None, extra_info: Mapping | None) -> None:

        self._close_data_file()
        for key in self.video_keys:
            self._close_video_file(key)
        shutil.rmtree(self.tmp / ".video-parts", ignore_errors=True)
        for key in self.video_keys:  # what LeRobot's update_video_info records, from the first file
            first = self.tmp / VIDEO_PATH.format(video_key=key, chunk_index=0, file_index=0)
            self.features[key] = {**self.features[key], "info": lerobot_video_info(first, self.video_gop)}
        self._flush_meta()
        self._fold_stats()
        if self.meta_writer is not None:
            self.meta_writer.close()
            self.meta_writer = None
        tasks_path = self.tmp / TASKS_PATH
        tasks_path.parent.mkdir(parents=True, exist_ok=True)
        tasks_path.write_bytes(_tasks_parquet(self.tasks))
        stats = {key: {stat: value.tolist() for stat, value in st.items()} for key, st in (self.stats or {}).items()}
        _write_json(self.tmp / STATS_PATH, stats)
        hub_envs_info: dict[str, Any] = {"seeds": list(self.seeds), "stats": STATS_NOTE}
        for key, value in (extra_info or {}).items():
            if key in hub_envs_info:  # seeds, stats
                raise ConfigError(f"extra_info may not set '{key}': hub-envs writes it. Rename that key.")
            hub_envs_info[key] = value
        info = {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": robot_type,
            "total_episodes": self.n_episodes,
            "total_frames": self.total_frames,
            "total_tasks": len(self.tasks),
            "chunks_size": self.chunks_size,
            "data_files_size_in_mb": self.file_mb,
            "video_files_size_in_mb": self.video_file_mb,
            "fps": self.fps,
            "splits": {"train": f"0:{self.n_episodes}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if self.video_keys else None,
            "features": self.features,
        }
        _write_json(self.tmp / INFO_PATH, info)
        try:
            _write_json(self.tmp / HUB_ENVS_META_PATH, hub_envs_info)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"extra_info must be JSON-serializable (str, numbers, bools, None, lists, dicts): {exc}") from exc

    def abort(self) -> None:
        for w in (self.data_writer, self.meta_writer):
            if w is not None:
                try:
                    w.close()
                except Exception:  # noqa: BLE001
                    pass


@functools.lru_cache(maxsize=16)
def _tasks_parquet(tasks: tuple[str, ...]) -> bytes:
    """``meta/tasks.parquet``: each task's text and its ``task_index``, in the layout the installed LeRobot's own writer
    gives (pandas; its index name changed in 0.5). The same bytes for the same tasks: made once per tuple (pandas'
    writer costs more than a small dataset's other metadata)."""
    import io

    import pandas as pd

    buffer = io.BytesIO()
    frame = pd.DataFrame({"task_index": list(range(len(tasks)))}, index=pd.Index(list(tasks), name=tasks_index_name()))
    frame.to_parquet(buffer)
    return buffer.getvalue()


def _next_file(chunk: int, file: int, chunks_size: int) -> tuple[int, int]:
    """lerobot.datasets.utils.update_chunk_file_indices."""
    return (chunk + 1, 0) if file == chunks_size - 1 else (chunk, file + 1)


def _write_json(path: Path, data: Any) -> None:
    """LeRobot's write_json (indent 4, no ASCII escaping), refusing NaN so output is strict JSON."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=4, ensure_ascii=False, allow_nan=False)
    path.write_text(text, encoding="utf-8")


def _progress(total: int | None, desc: str, enabled: bool):
    return tqdm(total=total, desc=desc, unit="ep", disable=not enabled, leave=False)


def write_lerobot_dataset(
    root: str | os.PathLike,
    *,
    repo_id: str,
    fps: int,
    features: Mapping[str, Mapping],
    episodes: Iterable[EpisodeFrames],
    task: str | Sequence[str],
    robot_type: str | None = None,
    extra_info: Mapping[str, Any] | None = None,
    progress: bool = True,
    overwrite: bool = False,
    chunks_size: int = DEFAULT_CHUNK_SIZE,
    data_files_size_in_mb: float = DEFAULT_DATA_FILE_SIZE_IN_MB,
    video_files_size_in_mb: float = DEFAULT_VIDEO_FILE_SIZE_IN_MB,
    encode_in_background: bool | None = None,
    video_gop: int | None = None,
) -> DatasetSummary:
    """Write ``episodes`` as a LeRobot v3.0 dataset folder at ``root`` and summarize it.

    Args:
        root: the dataset folder to create. It is written in a sibling temp folder and renamed into
            place at the end, so a failure leaves nothing (and an existing folder untouched).
        repo_id: the dataset's Hub id (LeRobot keeps it outside the files; used in the summary).
        fps: frames per second; ``timestamp = frame_index / fps``.
        features: info.json-style features of the recorded keys (not LeRobot's defaults
            ``timestamp``/``frame_index``/``episode_index``/``index``/``task_index``, added here).
            dtype ``"image"`` (shape ``[H, W, C]``, PNG in the parquet), ``"video"`` (shape ``[H, W, 3]``,
            MP4 files encoded by LeRobot's own encoder: :mod:`hub_envs.dataset.video`) or a numpy dtype name.
        episodes: :class:`EpisodeFrames`, consumed one at a time (memory stays bounded).
        task: the natural-language task of every frame (``meta/tasks.parquet``); or the tasks of a dataset of several, by
            ``task_index`` (each episode's :attr:`EpisodeFrames.task_index`; distinct texts: LeRobot indexes them by text).
        robot_type: ``info.json["robot_type"]``.
        extra_info: merged into ``meta/hub_envs.json`` next to ``"seeds"`` (JSON values only).
        progress: show a progress bar.
        overwrite: replace an existing folder at ``root`` (only once the new one is complete).
        chunks_size, data_files_size_in_mb, video_files_size_in_mb: LeRobot's file layout limits (defaults as LeRobot's).
        encode_in_background: encode camera frames (and compute their stats) while the next episodes are made: image
            features in a helper process (:mod:`hub_envs.dataset.png_process`), video features on a thread. False:
            inline. Default: when this process may use more than one CPU. The files are the same either way.
        video_gop: the keyframe interval of dtype ``"video"`` features (default
            :data:`hub_envs.dataset.video.DEFAULT_VIDEO_GOP`; 2 is LeRobot's own), recorded as ``video.g``.

    Raises:
        DatasetError: frames do not match ``features``, or the folder cannot be written.
        ConfigError: invalid arguments. Errors raised by the ``episodes`` iterable (e.g.
            :class:`hub_envs.errors.EnvCodeError` from rollouts) propagate unchanged; in every case
            nothing is left at ``root``.
    """
    root = Path(root)
    if not isinstance(fps, (int, np.integer)) or isinstance(fps, bool) or fps <= 0:
        raise ConfigError(f"fps={fps!r}: pass a positive integer.")
    tasks = (task,) if isinstance(task, str) else tuple(task)
    if not tasks or not all(isinstance(t, str) and t for t in tasks) or len(set(tasks)) != len(tasks):
        raise ConfigError("task must be a non-empty string, or a list of distinct ones (LeRobot stores one task per frame).")
    if chunks_size < 1 or data_files_size_in_mb <= 0 or video_files_size_in_mb <= 0:
        raise ConfigError("chunks_size, data_files_size_in_mb and video_files_size_in_mb must be positive.")
    if video_gop is not None:
        video_gop = check_video_gop(video_gop)
    feats = _normalize_features(features)
    if root.exists() and not overwrite:
        raise DatasetError(f"{root} already exists. Delete it, choose another folder, or pass overwrite=True.")
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
        tmp = root.parent / f".{root.name}.partial-{uuid.uuid4().hex[:12]}"
        tmp.mkdir()
    except OSError as exc:
        raise DatasetError(f"Cannot create the dataset folder next to {root}: {exc}. Check the path and permissions.") from exc

    writer = _Writer(
        tmp, feats, int(fps), tasks, int(chunks_size), data_files_size_in_mb, video_files_size_in_mb, video_gop=video_gop
    )
    try:
        total = len(episodes)  # type: ignore[arg-type]
    except TypeError:
        total = None
    bar = _progress(total, f"writing {root.name}", progress)
    try:
        background = _usable_cpus() > 1 if encode_in_background is None else bool(encode_in_background)
        _write_episodes(writer, episodes, background, bar)
        if writer.n_episodes == 0:
            raise DatasetError(f"No episodes were given for {root}; a LeRobot dataset needs at least one.")
        writer.finish(robot_type=robot_type, extra_info=extra_info)
        fingerprint = dataset_fingerprint(tmp)
        _move_into_place(tmp, root, overwrite)
    except BaseException as exc:
        writer.abort()
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, (HubEnvsError, KeyboardInterrupt, SystemExit, GeneratorExit)):
            raise
        if isinstance(exc, OSError):
            raise DatasetError(
                f"Writing the dataset at {root} failed: {exc}. Nothing was written; check disk space and permissions, then run again."
            ) from exc
        raise DatasetError(f"Writing the dataset at {root} failed: {type(exc).__name__}: {exc}. Nothing was written.") from exc
    finally:
        bar.close()
    return _summary(writer, root, repo_id, int(fps), feats, fingerprint)


def _usable_cpus() -> int:
    """The CPUs this process may run on (its affinity, e.g. a container's cpuset), not the machine's."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _write_episodes(writer: _Writer, episodes: Iterable[EpisodeFrames], background: bool, bar: Any) -> None:
    """Prepare, encode and write, in order: inline; or the camera frames encoded beside the episodes being made
    (image features only: in a helper process; with video features: on a thread)."""
    if not (writer.image_keys or writer.video_keys) or not background:
        for ep in episodes:
            writer.write(writer.encode(writer.prepare(ep)))
            bar.update(1)
        return
    encoder = png_process.acquire() if not writer.video_keys else None
    if encoder is not None:
        _write_encoded_elsewhere(writer, episodes, encoder, bar)
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="hub-envs-encode") as pool:
        pending: deque = deque()
        try:
            for ep in episodes:
                pending.append(pool.submit(writer.encode, writer.prepare(ep)))
                while len(pending) > 1:
                    writer.write(pending.popleft().result())
                    bar.update(1)
            while pending:
                writer.write(pending.popleft().result())
                bar.update(1)
        finally:
            for fut in pending:
                fut.cancel()


def _write_encoded_elsewhere(
    writer: _Writer, episodes: Iterable[EpisodeFrames], encoder: png_process.PngProcess, bar: Any
) -> None:
    """The image features' PNGs and stats made by ``encoder`` while the next episodes are made; the rest here."""
    pending: deque[_Episode] = deque()

    def write_oldest() -> None:
        ep = pending.popleft()
        writer.write(writer.encode(ep, images=encoder.result()))
        bar.update(1)

    finished = False
    try:
        for frames in episodes:
            ep = writer.prepare(frames)
            if encoder.full:
                write_oldest()
            encoder.submit([ep.columns[key] for key in writer.image_keys])
            pending.append(ep)
        while pending:
            write_oldest()
        finished = True
    finally:
        png_process.release(encoder, ok=finished)


def _summary(writer: _Writer, root: Path, repo_id: str, fps: int, feats: dict, fingerprint: str) -> DatasetSummary:
    returns = np.asarray(writer.returns, dtype=np.float64)
    return DatasetSummary(
        root=root,
        repo_id=repo_id,
        episodes=writer.n_episodes,
        frames=writer.total_frames,
        fps=fps,
        features=feats,
        episode_lengths=tuple(writer.lengths),
        seeds=tuple(writer.seeds),
        return_mean=float(returns.mean()) if returns.size else None,
        return_std=float(returns.std()) if returns.size else None,
        return_min=float(returns.min()) if returns.size else None,
        return_max=float(returns.max()) if returns.size else None,
        success_rate=float(np.mean(writer.successes)) if writer.successes else None,
        fingerprint=fingerprint,
    )


def _move_into_place(tmp: Path, root: Path, overwrite: bool) -> None:
    if root.exists():
        if not overwrite:
            raise DatasetError(f"{root} appeared while writing. Delete it or pass overwrite=True.")
        old = root.parent / f".{root.name}.old-{uuid.uuid4().hex[:12]}"
        os.rename(root, old)
        os.rename(tmp, root)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, root)
