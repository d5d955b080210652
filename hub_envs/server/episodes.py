"""The LeRobot v3 datasets the dataset viewer shows: found in a commit (an env repo's ``dataset/`` folder, or a
dataset repo's root), read lazily with pyarrow: the episodes metadata, and one episode's rows (only the row
groups that hold it, only the columns shown, a batch at a time), with bounded caches."""

from __future__ import annotations

import json
import math
import re
import string
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from hub_envs.server.storage import Commit, FileEntry, Repo

#: Where a repo holds its LeRobot dataset, tried in order: an env repo's ``dataset/`` folder (``push_env``), or
#: the root (a dataset repo, as LeRobot publishes them and ``push_env`` publishes the same dataset).
PREFIXES = {"model": ("dataset/",), "dataset": ("", "dataset/"), "space": ()}
INFO = "meta/info.json"
EPISODES_DIR = "meta/episodes/"
#: Columns of every frame that are bookkeeping, not data to plot.
BOOKKEEPING = ("timestamp", "frame_index", "episode_index", "index", "task_index")
MAX_INFO_BYTES = 4 * 1024 * 1024  # a larger info.json is not read
MAX_READ_BYTES = 512 * 1024 * 1024  # most uncompressed parquet bytes one request decodes (a batch at a time)
MAX_EPISODES = 200_000  # most episodes a dataset's index holds (a few hundred bytes each)
MAX_SERIES_VALUES = 2_000_000  # most numbers one episode's plots carry (steps x dimensions)
_BATCH_ROWS = 4096  # rows decoded at a time
_INDEX_CACHE = 8  # datasets whose episodes index is kept
_EPISODE_CACHE = 64  # episodes whose series are kept
_FRAME_CACHE_BYTES = 64 * 1024 * 1024  # PNG frames kept, all episodes together
_FIELDS = {"data_path": ("chunk_index", "file_index"), "video_path": ("video_key", "chunk_index", "file_index")}
_INT_SPEC = re.compile(r"^0?[1-9]?[0-9]?d?$")


class DatasetUnreadable(Exception):
    """A dataset (or one of its episodes) the viewer cannot show; the message says which file and why."""


@dataclass
class Dataset:
    """A LeRobot v3 dataset in one commit of a repo: its ``info.json`` and where its files are.

    Attributes:
        repo: the repo.
        commit: the commit shown.
        prefix: the folder the dataset is in (``"dataset/"`` or ``""``).
        info: ``meta/info.json``.
    """

    repo: Repo
    commit: Commit
    prefix: str
    info: dict
    features: dict[str, dict] = field(default_factory=dict)

    @property
    def fps(self) -> float:
        fps = self.info.get("fps")
        return float(fps) if isinstance(fps, (int, float)) and not isinstance(fps, bool) and 0 < fps < 1e6 else 30.0

    @property
    def video_keys(self) -> list[str]:
        return [k for k, f in self.features.items() if f.get("dtype") == "video"]

    @property
    def image_keys(self) -> list[str]:
        return [k for k, f in self.features.items() if f.get("dtype") == "image"]

    @property
    def series_keys(self) -> list[str]:
        """The numeric features of one dimension per frame (state, action, reward...), in the order to plot them."""
        keys = [
            k
            for k, f in self.features.items()
            if k not in BOOKKEEPING
            and f.get("dtype") in _NUMERIC
            and isinstance(f.get("shape"), list)
            and len(f["shape"]) == 1
            and isinstance(f["shape"][0], int)
            and 0 < f["shape"][0] <= 4096
        ]
        first = ("observation.state", "action", "next.reward")
        return sorted(keys, key=lambda k: (first.index(k) if k in first else len(first), keys.index(k)))

    def names(self, key: str) -> list[str]:
        """The names of a feature's dimensions (``info.json``'s ``names``), or ``key[i]``.

        Args:
            key: the feature.
        """
        feature = self.features.get(key, {})
        size = feature.get("shape", [1])[0]
        names = feature.get("names")
        if isinstance(names, dict):  # LeRobot also writes {"motors": [...]}
            names = next(iter(names.values()), None)
        if isinstance(names, list) and len(names) == size and all(isinstance(n, str) for n in names):
            return [n[:80] for n in names]
        return [key] if size == 1 else [f"{key}[{i}]" for i in range(size)]

    def file(self, path: str) -> FileEntry | None:
        """The commit's entry of ``path`` (relative to the dataset's folder), or None.

        Args:
            path: a path relative to the dataset's folder (``meta/info.json``).
        """
        return self.commit.files.get(self.prefix + path)

    def path(self, template_key: str, **values: Any) -> str:
        """A path from one of ``info.json``'s templates (``data_path``, ``video_path``), relative to the dataset.

        Args:
            template_key: ``data_path`` or ``video_path``.
            **values: the template's fields (``chunk_index``, ``file_index``, ``video_key``).

        Raises:
            DatasetUnreadable: the template is missing, or uses other fields or format specs than LeRobot's.
        """
        template = self.info.get(template_key)
        allowed = _FIELDS[template_key]
        if not isinstance(template, str) or not template or len(template) > 512:
            raise DatasetUnreadable(f"{self.prefix}{INFO}: {template_key} is not a path template.")
        try:
            parts = list(string.Formatter().parse(template))
        except ValueError:
            raise DatasetUnreadable(f"{self.prefix}{INFO}: {template_key} is not a valid path template.") from None
        for _, name, spec, conversion in parts:
            if name is None:
                continue
            if name not in allowed or conversion is not None or not _INT_SPEC.match(spec or "") or name == "video_key" and spec:
                raise DatasetUnreadable(f"{self.prefix}{INFO}: {template_key} uses {{{name[:40]}}}, not one of LeRobot's fields.")
        return template.format(**{k: v for k, v in values.items() if k in allowed})


_NUMERIC = {"float16", "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "bool"}


def find_dataset(repo: Repo, commit: Commit) -> Dataset | None:
    """The LeRobot v3 dataset ``commit`` holds, or None.

    Args:
        repo: the repo.
        commit: the commit.

    Returns:
        The dataset at the first of :data:`PREFIXES` (for the repo's type) that holds ``meta/info.json``.

    Raises:
        DatasetUnreadable: ``info.json`` is there but is not a LeRobot v3 one.
    """
    for prefix in PREFIXES.get(repo.repo_type, ()):
        entry = commit.files.get(prefix + INFO)
        if entry is None:
            continue
        if entry.size > MAX_INFO_BYTES:
            raise DatasetUnreadable(f"{prefix}{INFO} is larger than {MAX_INFO_BYTES // 2**20} MiB.")
        with repo.open_blob(entry) as f:
            raw = f.read(MAX_INFO_BYTES)
        try:
            info = json.loads(raw)
        except (ValueError, RecursionError):
            raise DatasetUnreadable(f"{prefix}{INFO} is not valid JSON.") from None
        if not isinstance(info, dict) or not isinstance(info.get("features"), dict):
            raise DatasetUnreadable(f"{prefix}{INFO} has no 'features': not a LeRobot dataset's info.")
        version = str(info.get("codebase_version", ""))
        if not version.startswith("v3"):
            raise DatasetUnreadable(
                f"{prefix}{INFO} is a LeRobot {version[:20] or 'unversioned'} dataset: the viewer reads v3.0 datasets."
            )
        features = {str(k): v for k, v in info["features"].items() if isinstance(v, dict)}
        return Dataset(repo, commit, prefix, info, features)
    return None


# --- the episodes index ---------------------------------------------------------------------------


@dataclass(slots=True)
class Episode:
    """One row of the episodes metadata: where the episode's frames and videos are, and what it did."""

    index: int
    length: int
    task: str | None
    data_file: tuple[int, int]  # (chunk, file) of its data parquet
    start: int  # its first frame's global index (dataset_from_index)
    stop: int  # one past its last (dataset_to_index)
    videos: dict[str, tuple[int, int, float, float]]  # key -> (chunk, file, from_timestamp, to_timestamp)
    success: bool | None  # from the episode's stats of next.success (max), if recorded
    ret: float | None  # the return: mean of next.reward times the length, if recorded
    seed: int | None


class EpisodeIndex:
    """A dataset's episodes, from its ``meta/episodes/`` parquet files (a few columns of each)."""

    def __init__(self, episodes: list[Episode]):
        self.episodes = sorted(episodes, key=lambda e: e.index)
        self._by_index = {e.index: e for e in self.episodes}

    def __len__(self) -> int:
        return len(self.episodes)

    def get(self, index: int) -> Episode | None:
        """Episode ``index`` (its ``episode_index``), or None.

        Args:
            index: the episode's ``episode_index``.
        """
        return self._by_index.get(index)


class EpisodeReader:
    """Reads episodes for the viewer, with bounded caches (episodes indexes, episodes' series, PNG frames)."""

    def __init__(self):
        self._guard = threading.Lock()
        self._indexes: OrderedDict[tuple, EpisodeIndex] = OrderedDict()
        self._series: OrderedDict[tuple, dict] = OrderedDict()
        self._frames: OrderedDict[tuple, list[bytes]] = OrderedDict()
        self._frame_bytes = 0
        self._metadata: OrderedDict[str, Any] = OrderedDict()  # parquet footers by blob sha256

    # -- caches --

    def _cached(self, cache: OrderedDict, key: tuple, size: int, make: Callable[[], Any]) -> Any:
        with self._guard:
            if key in cache:
                cache.move_to_end(key)
                return cache[key]
        value = make()
        with self._guard:
            cache[key] = value
            while len(cache) > size:
                cache.popitem(last=False)
        return value

    def _parquet(self, ds: Dataset, path: str) -> tuple[Any, Callable]:
        """``(metadata, open)`` of a parquet file of the dataset: its footer (cached) and how to open it."""
        import pyarrow.parquet as pq

        entry = ds.file(path)
        if entry is None:
            raise DatasetUnreadable(f"{ds.prefix}{path} is not in this revision.")

        def opened() -> Any:
            handle = ds.repo.open_blob(entry)
            return handle

        def footer() -> Any:
            with ds.repo.open_blob(entry) as f:
                try:
                    return pq.read_metadata(f)
                except Exception as err:  # pyarrow raises ArrowInvalid, OSError...: a damaged or hostile file
                    raise DatasetUnreadable(f"{ds.prefix}{path} is not a readable parquet file ({type(err).__name__}).") from None

        meta = self._cached(self._metadata, (entry.sha256,), 256, footer)
        return meta, opened

    # -- the index --

    def index(self, ds: Dataset) -> EpisodeIndex:
        """The dataset's episodes.

        Args:
            ds: the dataset.

        Returns:
            Its episodes index (cached by the content of its episodes files).

        Raises:
            DatasetUnreadable: no episodes metadata, or files that cannot be read.
        """
        files = sorted(
            p[len(ds.prefix) :] for p in ds.commit.files if p.startswith(ds.prefix + EPISODES_DIR) and p.endswith(".parquet")
        )
        if not files:
            raise DatasetUnreadable(f"{ds.prefix}{EPISODES_DIR} holds no parquet file: no episodes metadata.")
        key = tuple(ds.file(p).sha256 for p in files)  # type: ignore[union-attr]
        return self._cached(self._indexes, key, _INDEX_CACHE, lambda: EpisodeIndex(self._read_index(ds, files)))

    def _read_index(self, ds: Dataset, files: list[str]) -> list[Episode]:
        import pyarrow.parquet as pq

        videos = ds.video_keys
        wanted = ["episode_index", "length", "tasks", "data/chunk_index", "data/file_index", "dataset_from_index"]
        wanted += ["dataset_to_index", "stats/next.success/max", "stats/next.reward/mean", "seed"]
        for key in videos:
            wanted += [f"videos/{key}/{c}" for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")]
        out: list[Episode] = []
        for path in files:
            meta, opened = self._parquet(ds, path)
            names = set(_columns(meta))
            columns = [c for c in wanted if c in names]
            if "episode_index" not in names:
                raise DatasetUnreadable(f"{ds.prefix}{path} has no episode_index column: not LeRobot episodes metadata.")
            with opened() as handle, _unreadable(f"{ds.prefix}{path}"):
                pf = pq.ParquetFile(handle, metadata=meta)
                _check_size(pf, range(pf.num_row_groups), columns, f"{ds.prefix}{path}")
                for batch in pf.iter_batches(batch_size=_BATCH_ROWS, columns=columns):
                    rows = batch.to_pydict()
                    for i in range(batch.num_rows):
                        out.append(_episode(rows, i, videos))
                        if len(out) > MAX_EPISODES:
                            raise DatasetUnreadable(f"{ds.prefix}{EPISODES_DIR}: more than {MAX_EPISODES} episodes.")
        return out

    # -- one episode --

    def series(self, ds: Dataset, episode: Episode) -> dict:
        """One episode's numeric features, frame by frame, for the plots.

        Args:
            ds: the dataset.
            episode: the episode.

        Returns:
            ``{"keys": [{"key", "names", "values": [[dimension 0 values], ...]}], "timestamps": [...]}``; values
            that are not finite are None.

        Raises:
            DatasetUnreadable: its data file is missing or cannot be read, or it is too large to show.
        """
        keys = ds.series_keys
        total = episode.length * sum(len(ds.names(k)) for k in keys)
        if total > MAX_SERIES_VALUES:
            raise DatasetUnreadable(f"episode {episode.index} has {total} values to plot (more than {MAX_SERIES_VALUES}).")
        data_path = ds.path("data_path", chunk_index=episode.data_file[0], file_index=episode.data_file[1])
        entry = ds.file(data_path)
        if entry is None:
            raise DatasetUnreadable(f"{ds.prefix}{data_path} (episode {episode.index}'s data) is not in this revision.")
        cache_key = (entry.sha256, episode.start, episode.stop, tuple(keys))

        def read() -> dict:
            columns = {k: [] for k in [*keys, "timestamp"]}
            for batch in self._rows(ds, data_path, episode, [*keys, "timestamp"]):
                for k in columns:
                    if k in batch:
                        columns[k].extend(batch[k])
            out = []
            for k in keys:
                dims = len(ds.names(k))
                values = [[_finite(row[d] if isinstance(row, list) else row) for row in columns[k]] for d in range(dims)]
                out.append({"key": k, "names": ds.names(k), "values": values})
            return {"keys": out, "timestamps": [_finite(t) for t in columns["timestamp"]]}

        return self._cached(self._series, cache_key, _EPISODE_CACHE, read)

    def frame(self, ds: Dataset, episode: Episode, key: str, step: int) -> bytes:
        """One camera frame of an image feature (``dtype: image``), as the PNG the dataset stores.

        Args:
            ds: the dataset.
            episode: the episode.
            key: the image feature.
            step: the frame's index in the episode.

        Returns:
            The PNG's bytes.

        Raises:
            DatasetUnreadable: no such frame, or its file cannot be read.
        """
        if key not in ds.image_keys or not 0 <= step < episode.length:
            raise DatasetUnreadable(f"episode {episode.index} has no frame {step} of {key!r}.")
        data_path = ds.path("data_path", chunk_index=episode.data_file[0], file_index=episode.data_file[1])
        entry = ds.file(data_path)
        if entry is None:
            raise DatasetUnreadable(f"{ds.prefix}{data_path} (episode {episode.index}'s data) is not in this revision.")
        cache_key = (entry.sha256, episode.start, episode.stop, key)
        with self._guard:
            frames = self._frames.get(cache_key)
            if frames is not None:
                self._frames.move_to_end(cache_key)
        if frames is None:
            frames = []
            for batch in self._rows(ds, data_path, episode, [key]):
                frames += [cell.get("bytes") if isinstance(cell, dict) else None for cell in batch.get(key, [])]
            size = sum(len(f or b"") for f in frames)
            with self._guard:
                if size <= _FRAME_CACHE_BYTES and cache_key not in self._frames:
                    self._frames[cache_key] = frames
                    self._frame_bytes += size
                    while self._frame_bytes > _FRAME_CACHE_BYTES:
                        _, dropped = self._frames.popitem(last=False)
                        self._frame_bytes -= sum(len(f or b"") for f in dropped)
        if step >= len(frames) or not frames[step]:
            raise DatasetUnreadable(f"episode {episode.index} has no frame {step} of {key!r} in {ds.prefix}{data_path}.")
        return frames[step]

    def _rows(self, ds: Dataset, path: str, episode: Episode, columns: list[str]) -> Iterator[dict]:
        """The rows of ``episode`` in the data file ``path``, ``columns`` of them, a batch at a time (as lists):
        only the row groups whose ``index`` range meets the episode's are decoded."""
        import pyarrow.parquet as pq

        meta, opened = self._parquet(ds, path)
        names = _columns(meta)
        leaves = [meta.schema.column(i).path for i in range(meta.num_columns)]
        if "index" not in names or "index" not in leaves:
            raise DatasetUnreadable(f"{ds.prefix}{path} has no index column: not a LeRobot data file.")
        columns = [c for c in columns if c in names]
        index_col = leaves.index("index")
        groups = []
        for g in range(meta.num_row_groups):
            stats = meta.row_group(g).column(index_col).statistics
            if stats is not None and stats.has_min_max and (stats.max < episode.start or stats.min >= episode.stop):
                continue  # none of the episode's frames in this row group
            groups.append(g)
        with opened() as handle, _unreadable(f"{ds.prefix}{path}"):
            pf = pq.ParquetFile(handle, metadata=meta)
            _check_size(pf, groups, ["index", *columns], f"{ds.prefix}{path}")
            for batch in pf.iter_batches(batch_size=_BATCH_ROWS, row_groups=groups, columns=["index", *columns]):
                # rows of the episode, as runs of consecutive rows (one run in a LeRobot file: its index is sorted);
                # sliced, not filtered by pyarrow.compute: that imports pandas, seconds on a cold server
                index = batch.column("index").to_pylist()
                wanted = [i for i, v in enumerate(index) if v is not None and episode.start <= v < episode.stop]
                for first, count in _runs(wanted):
                    yield batch.slice(first, count).to_pydict()


@contextmanager
def _unreadable(where: str) -> Iterator[None]:
    """pyarrow's errors on a damaged or hostile file (ArrowInvalid, OSError...) as :class:`DatasetUnreadable`."""
    try:
        yield
    except DatasetUnreadable:
        raise
    except Exception as err:
        raise DatasetUnreadable(f"{where} cannot be read ({type(err).__name__}: {str(err)[:200]}).") from None


def _check_size(pf: Any, groups, columns: list[str], where: str) -> None:
    """Refuse to decode more than :data:`MAX_READ_BYTES` (uncompressed, the columns read) of a file."""
    meta = pf.metadata
    leaves = [meta.schema.column(i).path for i in range(meta.num_columns)]
    wanted = {i for i, n in enumerate(leaves) if n in columns or any(n.startswith(c + ".") for c in columns)}
    total = 0
    for g in groups:
        rg = pf.metadata.row_group(g)
        total += sum(rg.column(i).total_uncompressed_size for i in range(rg.num_columns) if i in wanted)
    if total > MAX_READ_BYTES:
        raise DatasetUnreadable(f"{where}: {total // 2**20} MiB to decode for one request, over the viewer's limit.")


def _runs(positions: list[int]) -> Iterator[tuple[int, int]]:
    """``(first, count)`` of each run of consecutive numbers in sorted ``positions``.

    >>> list(_runs([2, 3, 4, 9, 10]))
    [(2, 3), (9, 2)]
    """
    start = previous = None
    for p in positions:
        if start is None:
            start = previous = p
        elif p == previous + 1:
            previous = p
        else:
            yield start, previous - start + 1
            start = previous = p
    if start is not None:
        yield start, previous - start + 1


def _columns(meta: Any) -> list[str]:
    """A parquet file's top-level column names (``observation.state``, not its leaf ``...list.element``)."""
    try:
        return meta.schema.to_arrow_schema().names
    except Exception:  # a schema pyarrow cannot map back to Arrow: a damaged or hostile file
        raise DatasetUnreadable("a parquet file's schema cannot be read.") from None


def _int(value: Any) -> int | None:
    return int(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) else None


def _first(value: Any) -> Any:
    return value[0] if isinstance(value, list) and value else value


def _finite(value: Any) -> float | int | None:
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, (int, float)) and math.isfinite(value):
        return value
    return None


def _episode(rows: dict, i: int, videos: list[str]) -> Episode:
    def col(name: str) -> Any:
        return rows[name][i] if name in rows else None

    index = _int(col("episode_index"))
    if index is None:
        raise DatasetUnreadable("an episodes metadata row has no episode_index.")
    start, stop = _int(col("dataset_from_index")), _int(col("dataset_to_index"))
    length = _int(col("length"))
    if length is None and start is not None and stop is not None:
        length = stop - start
    tasks = col("tasks")
    task = str(tasks[0])[:500] if isinstance(tasks, list) and tasks else None
    success = _first(col("stats/next.success/max"))
    mean_reward = _first(col("stats/next.reward/mean"))
    spans = {}
    for key in videos:
        chunk, file = _int(col(f"videos/{key}/chunk_index")), _int(col(f"videos/{key}/file_index"))
        begin, end = col(f"videos/{key}/from_timestamp"), col(f"videos/{key}/to_timestamp")
        if chunk is not None and file is not None and isinstance(begin, (int, float)) and isinstance(end, (int, float)):
            spans[key] = (chunk, file, float(begin), float(end))
    return Episode(
        index=index,
        length=max(length or 0, 0),
        task=task,
        data_file=(_int(col("data/chunk_index")) or 0, _int(col("data/file_index")) or 0),
        start=start if start is not None else 0,
        stop=stop if stop is not None else 0,
        videos=spans,
        success=bool(success) if isinstance(success, (bool, int, float)) else None,
        ret=float(mean_reward) * (length or 0) if isinstance(mean_reward, (int, float)) and math.isfinite(mean_reward) else None,
        seed=_int(col("seed")),
    )
