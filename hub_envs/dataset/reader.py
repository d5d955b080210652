"""Read LeRobot v3.0 datasets without lerobot or torch: info, episodes metadata, frames, fingerprint.

The one reader of hub-envs (load's feature check, replay, reproduce, ``open_dataset`` checks): pyarrow over the
files the layout names, every path template checked so a hostile ``info.json`` cannot point outside the
dataset folder, images decoded by :mod:`hub_envs.dataset.codec`.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import string
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from hub_envs._text import safe_text
from hub_envs.dataset.codec import decode_pngs
from hub_envs.dataset.layout import DATA_PATH, EPISODES_DIR, HUB_ENVS_META_PATH, INFO_PATH, LEGACY_INFO_KEY, VIDEO_PATH
from hub_envs.dataset.video import decode_episode
from hub_envs.errors import DatasetError, IntegrityError

# --- files ------------------------------------------------------------------------------------


def dataset_fingerprint(root: str | os.PathLike) -> str:
    """sha256 over the dataset files under ``data/``, ``meta/`` and ``videos/`` of ``root``.

    For each file in sorted order of its relative POSIX path: the path, its size and its bytes.
    Files elsewhere (README.md, ``.cache/``) do not count.
    """
    root = Path(root)
    files = sorted(
        (p.relative_to(root).as_posix(), p)
        for top in ("data", "meta", "videos")
        if (root / top).is_dir()
        for p in (root / top).rglob("*")
        if p.is_file()
    )
    h = hashlib.sha256()
    for rel, path in files:
        h.update(f"{rel}\0{path.stat().st_size}\0".encode())
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


#: The fields LeRobot fills into ``info.json``'s path templates, all of them integers but ``video_key``.
_PATH_TEMPLATE_FIELDS = {"data_path": ("chunk_index", "file_index"), "video_path": ("video_key", "chunk_index", "file_index")}
_INT_FORMAT_SPEC = re.compile(r"^0?[1-9]?[0-9]?d?$")  # '', 'd', '03d', '06d', '3' ...


def _check_path_template(path: Path, key: str, template: Any) -> None:
    """``info[key]`` must be a format string of LeRobot's named fields only (no attribute or index lookups,
    no conversions, integer format specs) that stays inside the dataset root whatever the field values."""
    fields = _PATH_TEMPLATE_FIELDS[key]
    fix = (
        f"Do not use this dataset; its publisher must re-publish it with push_env (which writes {key} = {DATA_PATH!r})."
        if key == "data_path"
        else f"Do not use this dataset; its publisher must re-publish it with push_env (which writes {key} = {VIDEO_PATH!r})."
    )
    if not isinstance(template, str) or not template:
        raise DatasetError(f"{path}: {key} must be a non-empty path template string, got {safe_text(repr(template))}. {fix}")
    try:
        parts = list(string.Formatter().parse(template))
    except ValueError as exc:
        raise DatasetError(f"{path}: {key} {safe_text(repr(template))} is not a valid path template ({exc}). {fix}") from None
    literal = []
    for text, name, spec, conversion in parts:
        literal.append(text)
        if name is None:
            continue
        if name not in fields or conversion is not None or "{" in (spec or ""):
            raise DatasetError(
                f"{path}: {key} {safe_text(repr(template))} uses the field {{{safe_text(name)}"
                f"{'!' + conversion if conversion else ''}}}; only {', '.join('{' + f + '}' for f in fields)} are allowed "
                f"(no attribute or index lookups, no conversions). {fix}"
            )
        if name != "video_key" and not _INT_FORMAT_SPEC.match(spec or ""):
            raise DatasetError(
                f"{path}: {key} {safe_text(repr(template))}: {{{name}:{safe_text(spec)}}} is not an integer "
                f"format such as {{{name}:03d}}. {fix}"
            )
        literal.append("x")
    shape = "".join(literal)
    rel = PurePosixPath(shape)
    if "\\" in shape or "\x00" in shape or rel.is_absolute() or any(p in ("", ".", "..") for p in shape.split("/")):
        raise DatasetError(
            f"{path}: {key} {safe_text(repr(template))} leads outside the dataset folder (absolute, '..' "
            f"or empty path parts). {fix}"
        )


def read_info(root: str | os.PathLike) -> dict:
    """``meta/info.json`` as a dict (features, fps, totals; hub-envs' own keys are in :func:`read_hub_envs_meta`).

    Its ``data_path`` and ``video_path`` templates are checked (named integer fields only, no way out
    of ``root``), so a path built from them names a file of this dataset.
    """
    path = Path(root) / INFO_PATH
    try:
        with open(path, encoding="utf-8") as f:
            info = json.load(f)
    except FileNotFoundError as exc:
        raise DatasetError(
            f"{path} does not exist: {root} is not a LeRobot dataset folder. Generate or download it first."
        ) from exc
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path} is unreadable or not JSON ({exc}). Regenerate the dataset.") from exc
    except RecursionError:  # nested deeper than the parser goes: no info.json LeRobot writes
        raise DatasetError(
            f"{path} is nested too deeply to be a LeRobot info.json (not JSON this reader accepts). "
            f"Regenerate the dataset, or re-publish the env with push_env."
        ) from None
    if not isinstance(info, dict) or "features" not in info or "codebase_version" not in info:
        raise DatasetError(f"{path} lacks 'features' or 'codebase_version'; it is not a LeRobot v3.0 info.json.")
    if "data_path" in info:
        _check_path_template(path, "data_path", info["data_path"])
    if info.get("video_path") is not None:
        _check_path_template(path, "video_path", info["video_path"])
        features = info["features"] if isinstance(info["features"], dict) else {}
        for key, ft in features.items():  # LeRobot fills {video_key} with the feature's name
            if (
                isinstance(ft, dict)
                and ft.get("dtype") == "video"
                and ("/" in key or "\\" in key or "\x00" in key or key in ("", ".", ".."))
            ):
                raise DatasetError(
                    f"{path}: video feature {key!r} cannot name a folder of video_path (it holds '/', '\\' "
                    f"or is '.'/'..'). Do not use this dataset; its publisher must re-publish it."
                )
    return info


def read_hub_envs_meta(root: str | os.PathLike, info: Mapping | None = None) -> dict:
    """hub-envs' metadata of a dataset it wrote (``seeds``, ``stats``, ``env_meta``...), ``{}`` for any other dataset.

    Read from ``meta/hub_envs.json``; a dataset written before that file existed keeps the same object under
    ``info.json["hub_envs"]`` (``info``: that dataset's :func:`read_info`, read here when not given).

    Args:
        root: the dataset folder.
        info: its ``info.json`` already read (saves reading it again).

    Returns:
        The metadata as a dict.

    Raises:
        DatasetError: ``meta/hub_envs.json`` is there but is not a JSON object.
    """
    path = Path(root) / HUB_ENVS_META_PATH
    if path.is_file():
        try:
            meta = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:
            raise DatasetError(f"{path} is unreadable or not JSON ({type(exc).__name__}). Regenerate the dataset.") from None
        if not isinstance(meta, dict):
            raise DatasetError(f"{path} is not a JSON object. Regenerate the dataset, or re-publish the env with push_env.")
        return meta
    legacy = (info if info is not None else read_info(root)).get(LEGACY_INFO_KEY)
    return dict(legacy) if isinstance(legacy, Mapping) else {}


def data_file(root: str | os.PathLike, info: Mapping, chunk_index: Any, file_index: Any) -> Path:
    """The data file ``info["data_path"]`` names for ``(chunk_index, file_index)``, checked to lie inside ``root``.

    ``info`` must come from :func:`read_info` (which checks the template); the indices come from the
    episodes metadata and must be non-negative integers.
    """
    root = Path(root)
    for name, value in (("data/chunk_index", chunk_index), ("data/file_index", file_index)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise DatasetError(
                f"{root / EPISODES_DIR}: {name} {value!r} is not a non-negative integer. "
                f"The dataset is corrupt; re-download it or re-publish the env with push_env."
            )
    template = info.get("data_path", DATA_PATH)
    _check_path_template(root / INFO_PATH, "data_path", template)
    rel = template.format(chunk_index=int(chunk_index), file_index=int(file_index))
    parts = rel.split("/")
    if rel.startswith("/") or "\\" in rel or any(p in ("", ".", "..") for p in parts):  # cannot happen after the check
        raise DatasetError(
            f"{root / INFO_PATH}: data_path resolves to {rel!r}, outside the dataset folder. Re-publish with push_env."
        )
    return root.joinpath(*parts)


def video_file(root: str | os.PathLike, info: Mapping, key: str, meta: Mapping) -> Path:
    """The MP4 of video feature ``key`` that holds the episode ``meta`` (a :func:`read_episode_meta` row),
    checked as :func:`data_file` checks data files."""
    root = Path(root)
    values = []
    for name in ("chunk_index", "file_index"):
        value = meta.get(f"videos/{key}/{name}")
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise DatasetError(
                f"{root / EPISODES_DIR}: videos/{key}/{name} of episode {meta.get('episode_index')} is {value!r}, not a "
                f"non-negative integer. The dataset is corrupt; re-download it or re-publish the env with push_env."
            )
        values.append(int(value))
    template = info.get("video_path") or VIDEO_PATH
    _check_path_template(root / INFO_PATH, "video_path", template)
    rel = template.format(video_key=key, chunk_index=values[0], file_index=values[1])
    parts = rel.split("/")
    if rel.startswith("/") or "\\" in rel or any(p in ("", ".", "..") for p in parts):  # the key is checked by read_info
        raise DatasetError(
            f"{root / INFO_PATH}: video_path resolves to {rel!r}, outside the dataset folder. Re-publish with push_env."
        )
    return root.joinpath(*parts)


def read_episode_video(root: str | os.PathLike, info: Mapping, key: str, meta: Mapping) -> np.ndarray:
    """The decoded frames (uint8 ``(T, H, W, 3)``) of video feature ``key`` for the episode ``meta``.

    Raises :class:`hub_envs.errors.IntegrityError` for a missing, truncated or undecodable file."""
    path, start, where = _video_span(root, info, key, meta)
    return decode_episode(
        path,
        from_timestamp=start,
        length=int(meta["length"]),
        fps=int(info["fps"]),
        shape=tuple(info["features"][key]["shape"]),
        where=where,
    )


def _video_span(root: str | os.PathLike, info: Mapping, key: str, meta: Mapping) -> tuple[Path, float, str]:
    """(the MP4 of ``key`` holding episode ``meta``, the episode's start in it in seconds, a name for messages)."""

    path = video_file(root, info, key, meta)
    where = f"episode {meta['episode_index']}, {key}"
    if not path.is_file():
        raise IntegrityError(
            f"{path} ({where}) is missing. Fetch the dataset again (LoadedEnv.fetch_dataset()) or re-publish the env with push_env."
        )
    start = meta.get(f"videos/{key}/from_timestamp")
    if not isinstance(start, (int, float)) or isinstance(start, bool) or not np.isfinite(start) or start < 0:
        raise DatasetError(
            f"{Path(root) / EPISODES_DIR}: videos/{key}/from_timestamp of {where} is {start!r}. Re-publish with push_env."
        )
    return path, float(start), where


def check_videos(root: str | os.PathLike) -> int:
    """Open every MP4 the dataset's video features use and decode its last episode's frames (the part a
    truncation cuts off first); returns how many files were checked (0: no video features).

    Raises :class:`hub_envs.errors.IntegrityError` for a missing, truncated or undecodable file."""
    info = read_info(root)
    keys = [k for k, ft in info["features"].items() if isinstance(ft, dict) and ft.get("dtype") == "video"]
    if not keys:
        return 0
    last: dict[tuple[str, Any, Any], dict] = {}
    for m in read_episode_meta(root):
        for key in keys:
            last[(key, m.get(f"videos/{key}/chunk_index"), m.get(f"videos/{key}/file_index"))] = m
    for (key, _, _), m in last.items():
        read_episode_video(root, info, key, m)
    return len(last)


def read_episode_meta(root: str | os.PathLike) -> list[dict]:
    """One dict per episode (sorted by ``episode_index``): the episodes metadata without stats.

    Keys: episode_index, tasks, length, data/chunk_index, data/file_index, dataset_from_index,
    dataset_to_index, meta/episodes/chunk_index, meta/episodes/file_index and ``seed`` (``None``
    for datasets not written by hub-envs).
    """
    import pyarrow.parquet as pq  # heavy: pyarrow

    meta_dir = Path(root) / EPISODES_DIR
    paths = sorted(meta_dir.glob("*/*.parquet"))
    if not paths:
        raise DatasetError(f"No episode metadata under {meta_dir}: {root} is not a LeRobot v3.0 dataset folder.")
    rows: list[dict] = []
    try:
        for path in paths:
            with pq.ParquetFile(path) as f:  # small files: no dataset API, no thread pool
                names = f.schema_arrow.names
                table = f.read(columns=[n for n in names if not n.startswith("stats/")], use_threads=False)
            rows.extend(table.to_pylist())
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Cannot read episode metadata in {meta_dir}: {exc}. Regenerate the dataset.") from exc
    for row in rows:
        row.setdefault("seed", None)
    rows.sort(key=lambda r: r["episode_index"])
    return rows


def _numeric_column(col: Any, ft: Mapping, n: int) -> np.ndarray:
    """A numeric data column (scalar, ``Sequence`` or ``ArrayND``) -> ``(n, *shape)`` array of the feature's dtype."""
    import pyarrow.compute as pc  # heavy: pyarrow

    shape = tuple(ft["shape"])
    flat = col.storage if hasattr(col, "storage") else col  # datasets' ArrayND extension type
    for _ in range(len(shape) if shape != (1,) else 0):
        flat = pc.list_flatten(flat)
    return flat.to_numpy(zero_copy_only=False).astype(ft["dtype"], copy=False).reshape(n, *shape)


def _decode_column(col: Any, ft: Mapping, n: int) -> np.ndarray:
    if ft["dtype"] == "image":
        return decode_pngs(col.field("bytes").to_pylist(), tuple(ft["shape"]))
    return _numeric_column(col, ft, n)


def read_episode_frames(root: str | os.PathLike, episode_index: int, keys: Iterable[str] | None = None) -> dict[str, np.ndarray]:
    """The frames of one episode: ``{dataset_key: (T, *feature shape) array}`` (images and videos decoded, uint8 HWC).

    Reads only that episode's data file with pyarrow (row-group pruning on ``episode_index``);
    LeRobot's default columns are included. ``keys`` restricts the columns returned.
    """
    import pyarrow.parquet as pq  # heavy: pyarrow

    root = Path(root)
    info = read_info(root)
    features = info["features"]
    meta = [m for m in read_episode_meta(root) if m["episode_index"] == episode_index]
    if not meta:
        raise DatasetError(f"Episode {episode_index} is not in {root} ({info.get('total_episodes')} episodes).")
    m = meta[0]
    path = data_file(root, info, m["data/chunk_index"], m["data/file_index"])
    selected = None if keys is None else set(keys)
    wanted = [k for k in features if features[k]["dtype"] != "video" and (selected is None or k in selected)]
    columns = wanted if "episode_index" in wanted else [*wanted, "episode_index"]
    try:
        table = pq.read_table(path, columns=columns, filters=[("episode_index", "=", int(episode_index))])
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Cannot read {path}: {exc}. Regenerate or re-download the dataset.") from exc
    table = table.sort_by("frame_index") if "frame_index" in table.column_names else table
    n = table.num_rows
    if n != m["length"]:
        raise DatasetError(
            f"Episode {episode_index} has {n} rows in {path} but its metadata says {m['length']}. The dataset is corrupt; regenerate it."
        )
    out = {key: _decode_column(table.column(key).combine_chunks(), features[key], n) for key in wanted}
    for key, ft in features.items():
        if ft.get("dtype") == "video" and (selected is None or key in selected):
            out[key] = read_episode_video(root, info, key, m)
    return out


class DatasetFrames:
    """Many episodes' frames of some keys: each data file read once, numeric columns decoded up front,
    images kept as PNG bytes and decoded per episode by :meth:`episode`, videos decoded per episode from
    their MP4 (thread-safe, read only; episodes asked for in order are decoded front to back by one open
    decoder per file, :class:`hub_envs.dataset.video.EpisodeVideoReader`, freed by :meth:`close`).

    ``metas`` are :func:`read_episode_meta` rows of the episodes wanted; every episode must have exactly the
    rows its metadata says, in its data file.
    """

    def __init__(self, root: str | os.PathLike, info: Mapping, metas: list[dict], keys: list[str]):
        import pyarrow.parquet as pq  # heavy: pyarrow

        root = Path(root)
        features = info["features"]
        self.features = features
        self.root, self.info = root, info
        self.video_keys = [k for k in keys if features[k].get("dtype") == "video"]
        keys = [k for k in keys if k not in self.video_keys]
        self.metas = {m["episode_index"]: m for m in metas}
        self._videos: dict[tuple[Path, bool], Any] = {}  # (MP4, keyframes only) -> its EpisodeVideoReader
        self._videos_lock = threading.Lock()
        self.numeric: dict[int, dict[str, np.ndarray]] = {}
        self.images: dict[int, dict[str, Any]] = {}
        by_file: dict[tuple[int, int], list[int]] = {}
        for m in metas:
            by_file.setdefault((m["data/chunk_index"], m["data/file_index"]), []).append(m["episode_index"])
        lengths = {m["episode_index"]: int(m["length"]) for m in metas}
        for (chunk, file), episodes in by_file.items():
            path = data_file(root, info, chunk, file)  # info.json's data_path, checked to stay inside root
            try:
                with pq.ParquetFile(path) as f:
                    table = f.read(columns=[*keys, "episode_index", "frame_index"])
            except (OSError, ValueError, KeyError) as exc:
                raise DatasetError(f"Cannot read {path}: {exc}. Re-download or regenerate the dataset.") from exc
            ep_col = table.column("episode_index").to_numpy()
            order = np.lexsort((table.column("frame_index").to_numpy(), ep_col))
            if not np.all(order[:-1] < order[1:]):
                table, ep_col = table.take(order), ep_col[order]
            starts = {int(e): int(i) for e, i in zip(*np.unique(ep_col, return_index=True), strict=True)}
            columns: dict[str, Any] = {}
            for key in keys:
                col = table.column(key).combine_chunks()
                ft = features[key]
                columns[key] = col.field("bytes") if ft["dtype"] == "image" else _numeric_column(col, ft, len(table))
            for ep in episodes:
                if ep not in starts:
                    raise DatasetError(f"Episode {ep} has no rows in {path}. The dataset is corrupt; regenerate it.")
                lo = starts[ep]
                hi = lo + lengths[ep]
                if hi > len(ep_col) or ep_col[hi - 1] != ep or (hi < len(ep_col) and ep_col[hi] == ep):
                    raise DatasetError(
                        f"Episode {ep} in {path} does not have the {lengths[ep]} rows its metadata says. The dataset is corrupt; regenerate it."
                    )
                self.numeric[ep] = {k: v[lo:hi] for k, v in columns.items() if features[k]["dtype"] != "image"}
                self.images[ep] = {k: v.slice(lo, hi - lo) for k, v in columns.items() if features[k]["dtype"] == "image"}

    def episode(self, ep: int, keys: list[str] | None = None) -> dict[str, np.ndarray]:
        """The episode's frames; images decoded to uint8 (T, H, W, C)."""
        out = {k: v for k, v in self.numeric[ep].items() if keys is None or k in keys}
        for key, col in self.images[ep].items():
            if keys is None or key in keys:
                out[key] = decode_pngs(col.to_pylist(), tuple(self.features[key]["shape"]))
        for key in self.video_keys:
            if keys is None or key in keys:
                out[key] = self._video(key, self.metas[ep])
        return out

    def video_keyframes(self, ep: int, key: str) -> tuple[np.ndarray, np.ndarray]:
        """Episode ``ep``'s keyframes of video feature ``key``: ``(indices in the episode, uint8 (K, H, W, C))``
        (:meth:`hub_envs.dataset.video.EpisodeVideoReader.keyframes`)."""
        return self._video(key, self.metas[ep], keyframes=True)

    def _video(self, key: str, meta: Mapping, keyframes: bool = False) -> Any:
        from hub_envs.dataset.video import EpisodeVideoReader

        path, start, where = _video_span(self.root, self.info, key, meta)
        with self._videos_lock:  # one decoder per file and kind, one episode at a time
            reader = self._videos.get((path, keyframes))
            if reader is None:
                shape = tuple(self.features[key]["shape"])
                reader = self._videos[(path, keyframes)] = EpisodeVideoReader(
                    path, fps=int(self.info["fps"]), shape=shape, threads=1, keyframes_only=keyframes
                )
            read = reader.keyframes if keyframes else reader.episode
            return read(start, int(meta["length"]), where=where)

    def close(self) -> None:
        """Free the open video decoders (reading again reopens them)."""
        with self._videos_lock:
            for reader in self._videos.values():
                reader.close()
            self._videos.clear()
