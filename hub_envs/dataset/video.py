"""Camera features as video: LeRobot's own encoder in, pyav frames out, and how close "the same" is.

LeRobot stores camera features as MP4 by default (dtype ``"video"``): one file per camera and file index,
``videos/<key>/chunk-000/file-000.mp4``, episodes one after another, each episode's span recorded in the
episodes metadata as ``videos/<key>/from_timestamp`` / ``to_timestamp`` (seconds into the file). hub-envs
writes them the way LeRobot's ``save_episode`` does: each episode's frames become PNG files that
``lerobot.datasets.video_utils.encode_video_frames`` encodes (LeRobot's settings: AV1 via libsvtav1,
yuv420p, CRF 30; the GOP is :data:`DEFAULT_VIDEO_GOP`, see there), and the episodes of one file are joined with
LeRobot's ``concatenate_video_files`` (a remux, no re-encode). The encoder output is byte-deterministic for the
same frames (tested: same bytes run to run and across the two supported LeRobot stacks, whose pyav/libsvtav1
are the same), so datasets keep one fingerprint. The GOP is recorded as ``video.g`` in the feature's ``info``
(LeRobot 0.6 records its encoder settings there itself; absent means LeRobot's GOP 2).

The codec is lossy, so a replayed camera frame cannot equal the stored one bit for bit. Replay compares a
video feature frame by frame with :func:`frame_errors` (mean absolute difference over the frame's pixels, in
0-255 units) and accepts up to :data:`VIDEO_TOLERANCE`; everything else (states, actions, rewards, simulator
states, PNG images) stays exact. A frame that is a different picture (an object moved) differs by far more.
On top of the tolerance, the writer records each episode's :func:`frames_sha256` (of the frames as rendered,
before encoding) in the episodes metadata (:data:`hub_envs.dataset.layout.FRAMES_SHA256_COLUMN`), so replay can also tell that the env
renders exactly the recorded frames without a second encoder pass. :class:`EpisodeVideoReader` decodes a
file's episodes front to back with one open decoder, as replay reads them.

    >>> VIDEO_TOLERANCE.max_mean_abs_error
    8.0
    >>> import numpy as np
    >>> a = np.zeros((2, 4, 4, 3), np.uint8); b = a.copy(); b[1] += 10
    >>> frame_errors(a, b).tolist()
    [0.0, 10.0]
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hub_envs._compat import MAX_VIDEO_GOP, encode_video_frames, lerobot_video_utils
from hub_envs.dataset.codec import encode_png
from hub_envs.errors import ConfigError, DatasetError, IntegrityError

# libsvtav1 prints its configuration to stderr at info level for every file; errors only (LeRobot's own
# logging setting for libav is WARNING). An explicit setting by the user wins.
os.environ.setdefault("SVT_LOG", "1")

__all__ = [
    "VideoTolerance",
    "VIDEO_TOLERANCE",
    "DEFAULT_VIDEO_GOP",
    "check_video_gop",
    "frame_errors",
    "frames_sha256",
    "psnr",
    "encode_episode",
    "join_videos",
    "decode_episode",
    "EpisodeVideoReader",
]


@dataclass(frozen=True)
class VideoTolerance:
    """How far a decoded video frame may be from the frame the env renders, for replay to call them equal.

    ``max_mean_abs_error``: the mean over the frame's pixels and channels of ``|replay - decoded|`` (0-255).
    ``min_psnr_db`` is what that bound means as a peak signal-to-noise ratio for an error spread evenly
    (``20 log10(255 / max_mean_abs_error)``), stated for readers used to PSNR.
    """

    max_mean_abs_error: float
    codec: str = "av1 (libsvtav1), yuv420p, CRF 30 (LeRobot's defaults); GOP as recorded (video.g)"

    @property
    def min_psnr_db(self) -> float:
        return float(20 * np.log10(255.0 / self.max_mean_abs_error))

    def to_dict(self) -> dict:
        return {
            "metric": "per-frame mean |replay - decoded| over pixels and channels, 0-255",
            "max_mean_abs_error": self.max_mean_abs_error,
            "min_psnr_db": round(self.min_psnr_db, 2),
            "codec": self.codec,
        }


#: The bound replay applies to video features. Measured at LeRobot's CRF 30 (``benchmarks/bench_video.py``):
#: reach's 96x96 camera, 2000 frames, median 3.8 and worst 4.8 mean abs error at GOP 2 (lowest PSNR 27.5 dB),
#: 4.0 and 5.1 at GOP 10 (27.0 dB); 8 leaves room for other renders while a different picture (a moved camera,
#: other colours) is far above it.
VIDEO_TOLERANCE = VideoTolerance(max_mean_abs_error=8.0)

#: The keyframe interval of the videos push_env writes (``push_env(video_gop=...)``, ``--video_gop``). Not LeRobot's
#: 2, on purpose: an env repo's dataset is downloaded by every user who opens it and is read mostly front to back
#: (replay), where LeRobot's 2 is tuned for a training dataloader's random access. Measured on reach (96x96, 20
#: episodes x 100 frames, ``benchmarks/bench_video.py``), GOP 2 / 4 / 10 / 20: dataset bytes 0.41 / 0.28 / 0.19 /
#: 0.16 of the PNG dataset's; one frame at a random time decoded by LeRobot's ``decode_video_frames`` (pyav) 1.3 /
#: 1.6 / 2.0 / 2.9 ms. At 10 the dataset is under a fifth of its PNG size for 0.7 ms more per randomly accessed
#: frame. ``video_gop=2`` gives LeRobot's own bytes, for a dataset meant for training.
DEFAULT_VIDEO_GOP = 10


def check_video_gop(gop: object, *, name: str = "video_gop") -> int:
    """``gop`` as a keyframe interval (frames), or a :class:`~hub_envs.errors.ConfigError` naming ``name``.

    >>> check_video_gop(10), check_video_gop(2)
    (10, 2)
    """
    if isinstance(gop, bool) or not isinstance(gop, (int, np.integer)) or not 0 < gop <= MAX_VIDEO_GOP:
        raise ConfigError(
            f"{name}={gop!r}: pass a keyframe interval in frames, 1 to {MAX_VIDEO_GOP} "
            f"(push_env's default {DEFAULT_VIDEO_GOP}; LeRobot's is 2)."
        )
    return int(gop)


#: the smallest frame side LeRobot's AV1 encoder takes here: libsvtav1 dies with SIGFPE (the whole process, no
#: exception) on frames narrower than 28 px (measured: 24 px crashes, 28 px encodes); push stores such cameras as PNGs
MIN_VIDEO_SIDE = 32


def frame_errors(replay: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Per-frame mean ``|replay - data|`` (uint8 frames ``(T, H, W, C)``) as float64."""
    n = min(len(replay), len(data))
    if n == 0:
        return np.zeros(0)
    a = np.ascontiguousarray(replay[:n]).reshape(n, -1)
    b = np.ascontiguousarray(data[:n]).reshape(n, -1)
    if a.dtype == b.dtype == np.uint8:  # |a - b| without widening: OpenCV's absdiff (LeRobot's dependency), else max - min
        absdiff = _cv2_absdiff()
        diff = absdiff(a, b) if absdiff is not None else np.maximum(a, b) - np.minimum(a, b)
        return diff.sum(axis=1, dtype=np.uint64) / diff.shape[1]  # exact integer sums: the same means as float64
    diff = np.abs(a.astype(np.int16) - b.astype(np.int16))
    return diff.mean(axis=1, dtype=np.float64)


def _cv2_absdiff() -> Any:
    try:
        import cv2  # heavy: opencv
    except ImportError:  # pragma: no cover - LeRobot depends on opencv
        return None
    return cv2.absdiff


def frames_sha256(frames: np.ndarray) -> str:
    """sha256 (hex) of one episode's uint8 ``(T, H, W, C)`` frames: their shape, then their bytes in C order.

    >>> a = np.zeros((2, 4, 4, 3), np.uint8)
    >>> frames_sha256(a) == frames_sha256(a.copy()), frames_sha256(a) == frames_sha256(a[:1])
    (True, False)
    """
    frames = np.ascontiguousarray(frames)
    h = hashlib.sha256(f"{frames.dtype.str}{tuple(frames.shape)}\0".encode())
    h.update(memoryview(frames).cast("B"))  # hashlib releases the GIL on large buffers
    return h.hexdigest()


def psnr(replay: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Per-frame PSNR in dB (``inf`` for identical frames)."""
    n = min(len(replay), len(data))
    mse = ((replay[:n].astype(np.float64) - data[:n]) ** 2).reshape(n, -1).mean(axis=1)
    with np.errstate(divide="ignore"):
        return 10 * np.log10(255.0**2 / mse)


# --- writing ----------------------------------------------------------------------------------


@contextlib.contextmanager
def _scheduling_kept():
    """Restore the calling thread's scheduling policy after the block. libsvtav1 (LeRobot's AV1 encoder,
    through pyav) switches the thread that opens an encoder to SCHED_FIFO at priority 99 when it runs as root;
    every process forked afterwards (rollout pools, isolated env workers, servers) inherits that, and a busy
    real-time process never yields its core: a hung env then starves the process that should time it out."""
    try:
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    except (AttributeError, OSError):  # not Linux
        yield
        return
    try:
        yield
    finally:
        try:
            if (os.sched_getscheduler(0), os.sched_getparam(0)) != (policy, param):
                os.sched_setscheduler(0, policy, param)
        except OSError:
            pass


def encode_episode(frames: np.ndarray, out: Path, fps: int, gop: int = DEFAULT_VIDEO_GOP) -> tuple[Path, float, int]:
    """Encode one episode's ``(T, H, W, 3)`` uint8 frames to ``out`` with LeRobot's ``encode_video_frames``,
    keyframes every ``gop`` frames.

    The frames go through PNG files in a scratch folder beside ``out`` (the encoder's input, as in LeRobot's
    ``save_episode``; removed after). Returns ``(out, duration in seconds as LeRobot probes it, size in bytes)``.
    """
    video_utils = lerobot_video_utils()
    gop = check_video_gop(gop)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise DatasetError(f"{out.name}: video frames must be uint8 (T, H, W, 3), got {frames.dtype} {frames.shape}.")
    if min(frames.shape[1:3]) < MIN_VIDEO_SIDE:
        raise DatasetError(
            f"{out.name}: frames of {frames.shape[1]}x{frames.shape[2]} px are below the {MIN_VIDEO_SIDE} px LeRobot's AV1 "
            f"encoder (libsvtav1) can take (it crashes the process on them). Push with --video=false: the frames "
            f"are stored as PNGs."
        )
    scratch = out.parent / f".{out.stem}-frames"
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        for i, png in enumerate(encode_png(frames)):
            (scratch / f"frame-{i:06d}.png").write_bytes(png)
        with _scheduling_kept():
            encode_video_frames(scratch, out, fps, gop=gop)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return out, float(video_utils.get_video_duration_in_s(out)), out.stat().st_size


def join_videos(parts: list[Path], out: Path) -> None:
    """``out`` = the episode videos ``parts`` one after another (LeRobot's ``concatenate_video_files``, a remux;
    a single part is moved, as LeRobot does for a file's first episode). The parts are removed."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if len(parts) == 1:
        os.replace(parts[0], out)
        return
    lerobot_video_utils().concatenate_video_files(list(parts), out)
    for part in parts:
        part.unlink(missing_ok=True)


# --- reading ----------------------------------------------------------------------------------


def decode_episode(path: Path, *, from_timestamp: float, length: int, fps: int, shape: tuple[int, ...], where: str) -> np.ndarray:
    """The ``length`` frames of one episode, starting ``from_timestamp`` seconds into ``path``: uint8 ``(T, H, W, C)``.

    Frames are matched by their presentation time (frame ``i`` at ``from_timestamp + i / fps``, within half a
    frame). A file that cannot be opened or decoded, or that holds fewer frames than the metadata says
    (truncated), raises :class:`IntegrityError` naming the file.
    """
    with EpisodeVideoReader(path, fps=fps, shape=shape, threads=0) as reader:
        return reader.episode(from_timestamp, length, where=where)


_DECODE_FIX = (
    "The video file is truncated or corrupt: delete it and fetch the dataset again (LoadedEnv.fetch_dataset() "
    "checks every file against the manifest), or re-publish the env with push_env."
)


class EpisodeVideoReader:
    """The episodes of one MP4, decoded front to back by one open decoder: reading the episode that starts
    where the last one ended continues decoding there (no re-open, no seek back to a keyframe); any other
    episode is sought as :func:`decode_episode` does. Not thread-safe; :meth:`close` (or ``with``) frees it.

    ``threads``: decoder threads (0: FFmpeg's choice; 1 costs the least CPU, for a reader that runs beside
    other work, as replay's background reader does). ``keyframes_only``: the reader serves :meth:`keyframes`
    (the packets are read, only the keyframes decoded: a tenth of the decoding at push's GOP 10) instead of
    :meth:`episode`.
    """

    def __init__(self, path: Path, *, fps: int, shape: tuple[int, ...], threads: int = 1, keyframes_only: bool = False):
        self.path, self.fps, self.shape, self.threads = Path(path), int(fps), tuple(shape), int(threads)
        self.keyframes_only = keyframes_only
        self._container: Any = None
        self._codec: Any = None
        self._items: Any = None  # the decoder's frames, or the demuxer's packets (keyframes_only)
        self._tb = 0.0
        self._pending: Any = None  # a frame (packet) beyond the last episode's end: the next episode's first
        self._next: float | None = None  # the timestamp at which the next sequential episode starts

    def __enter__(self) -> EpisodeVideoReader:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        if self._container is not None:
            try:
                self._container.close()
            except Exception:  # noqa: BLE001 - closing a reader must not mask a result or an error
                pass
        self._container = self._codec = self._items = self._pending = self._next = None

    def _open(self, from_timestamp: float) -> None:
        import av  # heavy: pyav

        self.close()
        container = av.open(str(self.path), "r")
        try:
            stream = container.streams.video[0]
            if self.threads:
                stream.codec_context.thread_count = self.threads
            self._tb = float(stream.time_base)
            if from_timestamp > 0:
                container.seek(int(from_timestamp / self._tb), stream=stream, backward=True, any_frame=False)
            self._codec = stream.codec_context
            self._items = container.demux(stream) if self.keyframes_only else container.decode(stream)
        except BaseException:
            container.close()
            raise
        self._container = container

    def _span(self, from_timestamp: float, length: int, where: str):
        """Yield ``(index in the episode, frame or packet)`` for the episode's span, in stream order; checks that
        every one of its ``length`` frames is there (a packet per frame when ``keyframes_only``)."""
        import av  # heavy: pyav

        fps, path = self.fps, self.path
        seen = np.zeros(length, dtype=bool)
        end = from_timestamp + (length - 0.5) / fps
        try:
            if self._next is None or abs(from_timestamp - self._next) > 0.5 / fps:
                self._open(from_timestamp)  # not where the last episode ended: seek
            self._next = None
            item, self._pending = self._pending, None
            while True:
                if item is None:
                    item = next(self._items, None)
                    if item is None:
                        break
                if item.pts is not None and (not self.keyframes_only or item.size):
                    t = item.pts * self._tb
                    if t > end:
                        self._pending = item  # the next episode's first, when it is read next
                        break
                    i = round((t - from_timestamp) * fps)
                    if 0 <= i < length and abs(t - from_timestamp - i / fps) <= 0.5 / fps:
                        yield i, item
                        seen[i] = True
                item = None
        except IntegrityError:
            self.close()
            raise
        except (OSError, ValueError, IndexError, av.FFmpegError) as exc:
            self.close()
            raise IntegrityError(f"{path} ({where}) cannot be decoded: {type(exc).__name__}: {exc}. {_DECODE_FIX}") from None
        if not seen.all():
            self.close()
            raise IntegrityError(
                f"{path} ({where}) holds {int(seen.sum())} of the episode's {length} frames from {from_timestamp:.4f} s. {_DECODE_FIX}"
            )
        self._next = from_timestamp + length / fps

    def _array(self, frame: Any, where: str) -> np.ndarray:
        img = frame.to_ndarray(format="rgb24")
        if img.shape != self.shape:
            self.close()
            raise IntegrityError(
                f"{self.path} ({where}): frames are {img.shape}, the dataset declares {self.shape}. {_DECODE_FIX}"
            )
        return img

    def episode(self, from_timestamp: float, length: int, *, where: str) -> np.ndarray:
        """The ``length`` frames from ``from_timestamp`` (seconds into the file): uint8 ``(T, H, W, C)``.

        Raises:
            IntegrityError: the file cannot be opened or decoded, holds frames of another size, or fewer frames
                than asked for from there (truncated).
        """
        if self.keyframes_only:
            raise ValueError("this reader decodes keyframes only: use keyframes()")
        out = np.empty((length, *self.shape), dtype=np.uint8)
        for i, frame in self._span(from_timestamp, length, where):
            out[i] = self._array(frame, where)
        return out

    def keyframes(self, from_timestamp: float, length: int, *, where: str) -> tuple[np.ndarray, np.ndarray]:
        """``(indices, frames)``: the episode's keyframes (its first frame and every GOP-th one, as push and LeRobot
        encode), decoded on their own: their indices in the episode and uint8 ``(K, H, W, C)``.

        Raises:
            IntegrityError: as :meth:`episode` (a packet missing for any frame of the episode counts as truncated).
        """
        import av  # heavy: pyav

        if not self.keyframes_only:
            raise ValueError("this reader decodes every frame: use episode()")
        wanted: dict[int, int] = {}  # pts -> index
        frames: dict[int, np.ndarray] = {}
        try:
            for i, packet in self._span(from_timestamp, length, where):
                if packet.is_keyframe:
                    wanted[packet.pts] = i
                    for frame in self._codec.decode(packet):  # a keyframe decodes on its own
                        if frame.pts in wanted:
                            frames[wanted[frame.pts]] = self._array(frame, where)
            if len(frames) < len(wanted):  # a decoder that holds frames back: drain it (and start afresh next time)
                for frame in self._codec.decode(None):
                    if frame.pts in wanted:
                        frames[wanted[frame.pts]] = self._array(frame, where)
                self.close()
        except (OSError, ValueError, IndexError, av.FFmpegError) as exc:
            self.close()
            raise IntegrityError(f"{self.path} ({where}) cannot be decoded: {type(exc).__name__}: {exc}. {_DECODE_FIX}") from None
        if len(frames) < len(wanted):
            raise IntegrityError(
                f"{self.path} ({where}): {len(wanted) - len(frames)} keyframes of the episode do not decode. {_DECODE_FIX}"
            )
        index = np.array(sorted(frames), dtype=np.int64)
        return index, (np.stack([frames[i] for i in index]) if len(index) else np.zeros((0, *self.shape), np.uint8))
