"""Video datasets: camera features encoded by LeRobot's own encoder, decoded by LeRobotDataset, replayed
within the codec's declared tolerance; a damaged MP4 is an integrity error.

One module-scoped Hub and one push of a short reach (2 episodes x 12 steps, 96x96 camera) serve the push,
load, reproduce and LeRobotDataset tests; the writer tests use a small numpy-drawn camera (32x32).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import copy_env, saved_figures

from hub_envs import errors, load_env, push_env, reproduce
from hub_envs.dataset.reader import dataset_fingerprint, read_episode_frames, read_info
from hub_envs.dataset.video import VIDEO_TOLERANCE, frame_errors
from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset

ENVS = Path(__file__).resolve().parent.parent / "envs"
S = 32
FPS = 10


def _frames(i: int, n: int) -> np.ndarray:
    """A camera: a moving square on a colour ramp (smooth enough for a lossy codec to keep close)."""
    yy, xx = np.mgrid[0:S, 0:S]
    out = np.zeros((n, S, S, 3), np.uint8)
    for t in range(n):
        out[t, ..., 0] = xx * 4 + t * 3 + i * 10
        out[t, ..., 1] = yy * 6
        out[t, ..., 2] = 90
        x = (t * 2 + i) % (S - 8)
        out[t, 10:18, x : x + 8] = (250, 250, 40)
    return out


FEATURES = {
    "observation.state": {"dtype": "float32", "shape": [2], "names": ["x", "v"]},
    "observation.image": {"dtype": "video", "shape": [S, S, 3], "names": ["height", "width", "channels"]},
    "action": {"dtype": "float32", "shape": [1], "names": ["u"]},
}
LENGTHS = [10, 13, 7]


def _episodes(features=FEATURES):
    for i, n in enumerate(LENGTHS):
        frames = {
            "observation.state": np.full((n, 2), i, np.float32),
            "observation.image": _frames(i, n),
            "action": np.arange(n, dtype=np.float32)[:, None],
        }
        yield EpisodeFrames(i, seed=100 + i, frames=frames)


def _write(root: Path, features=FEATURES, **kw):
    return write_lerobot_dataset(
        root, repo_id="test/cam", fps=FPS, features=features, episodes=_episodes(features), task="watch", progress=False, **kw
    )


@pytest.fixture(scope="module")
def video_ds(tmp_path_factory):
    root = tmp_path_factory.mktemp("video") / "ds"
    return root, _write(root)


def test_video_layout_is_lerobots_v3(video_ds):
    root, summary = video_ds
    assert (root / "videos/observation.image/chunk-000/file-000.mp4").is_file()
    info = read_info(root)
    assert info["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    ft = info["features"]["observation.image"]
    assert ft["dtype"] == "video" and ft["shape"] == [S, S, 3]
    assert ft["info"]["video.codec"] == "av1" and ft["info"]["video.fps"] == FPS and ft["info"]["video.pix_fmt"] == "yuv420p"
    import pyarrow.parquet as pq

    assert "observation.image" not in pq.read_schema(root / "data/chunk-000/file-000.parquet").names
    meta = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    starts = np.cumsum([0, *LENGTHS[:-1]]) / FPS
    np.testing.assert_allclose(meta["videos/observation.image/from_timestamp"], starts)
    np.testing.assert_allclose(meta["videos/observation.image/to_timestamp"], starts + np.array(LENGTHS) / FPS)
    assert summary.frames == sum(LENGTHS)


def test_reader_decodes_each_episode_within_the_tolerance(video_ds):
    root, _ = video_ds
    for i, n in enumerate(LENGTHS):
        got = read_episode_frames(root, i)
        assert got["observation.image"].shape == (n, S, S, 3)
        errors_ = frame_errors(got["observation.image"], _frames(i, n))
        assert errors_.max() <= VIDEO_TOLERANCE.max_mean_abs_error, errors_
        # each decoded frame is closest to its own source frame, not a neighbour's (no off-by-one)
        if n > 1:
            shifted = frame_errors(got["observation.image"][1:], _frames(i, n)[:-1])
            assert (shifted > errors_[1:]).all()
        np.testing.assert_array_equal(got["action"][:, 0], np.arange(n))


@pytest.mark.parametrize("order", [[0, 1, 2], [2, 0, 1], [1, 1, 0, 2, 2]], ids=["in-order", "shuffled", "repeats"])
def test_one_open_reader_decodes_episodes_in_any_order(video_ds, order):
    """Replay's reader keeps one decoder per file: episodes read front to back continue where the last ended,
    any other order seeks; every episode is exactly what a fresh decode of it gives."""
    from hub_envs.dataset.reader import DatasetFrames, read_episode_meta

    root, _ = video_ds
    info, metas = read_info(root), read_episode_meta(root)
    alone = [read_episode_frames(root, i)["observation.image"] for i in range(len(LENGTHS))]
    frames = DatasetFrames(root, info, metas, ["observation.image"])
    try:
        for i in order:
            np.testing.assert_array_equal(frames.episode(i)["observation.image"], alone[i], err_msg=f"episode {i}")
    finally:
        frames.close()
    np.testing.assert_array_equal(frames.episode(1)["observation.image"], alone[1])  # closed readers reopen
    frames.close()


def test_frame_errors_are_the_mean_absolute_difference():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (5, 7, 9, 3), dtype=np.uint8)
    b = rng.integers(0, 256, (5, 7, 9, 3), dtype=np.uint8)
    expected = np.abs(a.astype(np.int64) - b).reshape(5, -1).mean(axis=1)
    np.testing.assert_array_equal(frame_errors(a, b), expected)
    np.testing.assert_array_equal(frame_errors(a[:, ::-1], b[:, ::-1]), expected)  # not contiguous
    np.testing.assert_array_equal(frame_errors(a, b[:3]), expected[:3])
    assert frame_errors(a, a).tolist() == [0.0] * 5


def test_the_writer_records_each_episodes_rendered_frames_sha256(video_ds):
    import pyarrow.parquet as pq

    from hub_envs.dataset.video import frames_sha256

    root, _ = video_ds
    meta = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    assert meta["frames_sha256/observation.image"] == [frames_sha256(_frames(i, n)) for i, n in enumerate(LENGTHS)]
    assert len(set(meta["frames_sha256/observation.image"])) == len(LENGTHS)


def _packets(path: Path) -> list[tuple[int | None, bool, bytes]]:
    import av

    with av.open(str(path)) as container:
        return [(p.pts, p.is_keyframe, bytes(p)) for p in container.demux(video=0) if p.size]


@pytest.mark.parametrize("gop", [3, 10])
def test_the_stream_has_a_key_frame_every_gop_frames_of_each_episode(tmp_path, gop):
    """The GOP is applied, not just recorded: in the joined file, key frames stand at every episode's first frame
    and every ``gop`` frames after it (on both stacks: 0.4's encoder takes ``g=``, 0.6's an encoder config)."""
    from hub_envs._compat import video_gop

    root = tmp_path / "ds"
    _write(root, video_gop=gop)
    keys = [i for i, (_, key, _) in enumerate(_packets(root / "videos/observation.image/chunk-000/file-000.mp4")) if key]
    starts = np.cumsum([0, *LENGTHS[:-1]])
    assert keys == [int(s) + t for s, n in zip(starts, LENGTHS) for t in range(0, n, gop)]
    assert video_gop(read_info(root)["features"]["observation.image"]["info"]) == gop


@pytest.mark.parametrize("gop", [2, 10], ids=["lerobot-gop", "default-gop"])
def test_video_dataset_matches_lerobot_own_writer(tmp_path, gop):
    """Same frames through LeRobot's add_frame/save_episode (video on, the same GOP) and ours: same files, same
    metadata columns, same video info (``video.g`` included), the same decoded tensors from LeRobotDataset (our
    MP4s are LeRobot's bytes). GOP 2 is LeRobot's default; 10 is push_env's, which LeRobot >= 0.5 can be told
    (``rgb_encoder=``); 0.4's writer has no GOP setting."""
    import dataclasses

    import pyarrow.parquet as pq
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from hub_envs._compat import LEROBOT_VIDEO_GOP, video_backend, video_gop

    encoder = {}
    if gop != LEROBOT_VIDEO_GOP:
        try:
            from lerobot.configs.video import rgb_encoder_defaults
        except ImportError:
            pytest.skip("LeRobot 0.4's dataset writer always encodes with GOP 2")
        encoder = {"rgb_encoder": dataclasses.replace(rgb_encoder_defaults(), g=gop)}
    ours = tmp_path / "ours"
    _write(ours, video_gop=gop)
    theirs = tmp_path / "theirs"
    ref = LeRobotDataset.create(
        "test/ref",
        fps=FPS,
        features={k: {**f, "shape": tuple(f["shape"])} for k, f in FEATURES.items()},
        root=theirs,
        use_videos=True,
        **encoder,
    )
    for ep in _episodes():
        for t in range(ep.length):
            ref.add_frame({k: (v[t] if v.ndim > 1 else v[t : t + 1]) for k, v in ep.frames.items()} | {"task": "watch"})
        ref.save_episode()
    ref.finalize()
    files = sorted(str(p.relative_to(theirs)) for p in theirs.rglob("*") if p.is_file() and "images" not in p.parts)
    ours_files = sorted(str(p.relative_to(ours)) for p in ours.rglob("*") if p.is_file())
    assert files == [f for f in ours_files if f != "meta/hub_envs.json"] and "meta/hub_envs.json" in ours_files  # + hub-envs' own
    video = "videos/observation.image/chunk-000/file-000.mp4"
    if gop == LEROBOT_VIDEO_GOP:
        assert (ours / video).read_bytes() == (theirs / video).read_bytes()  # LeRobot's encoder, LeRobot's bytes
    else:  # LeRobot remuxes a file episode by episode, hub-envs once: the container's bitrate estimate (btrt) may differ
        assert _packets(ours / video) == _packets(theirs / video)  # the same AV1 stream, packet for packet
    info_a, info_b = read_info(ours), read_info(theirs)
    assert info_a["features"] == json.loads(json.dumps(info_b["features"]))
    assert video_gop(info_a["features"]["observation.image"]["info"]) == gop
    assert info_a["video_path"] == info_b["video_path"]
    ma = pq.read_schema(ours / "meta/episodes/chunk-000/file-000.parquet")
    mb = pq.read_schema(theirs / "meta/episodes/chunk-000/file-000.parquet")
    assert [n for n in ma.names if n != "seed" and not n.startswith("frames_sha256/")] == mb.names  # hub-envs' columns
    ta = pq.read_table(ours / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    tb = pq.read_table(theirs / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    for col in (c for c in mb.names if c.startswith("videos/")):
        np.testing.assert_allclose(ta[col], tb[col], err_msg=col)
    backend = video_backend()
    a = LeRobotDataset("test/ours", root=ours, video_backend=backend)
    b = LeRobotDataset("test/ref", root=theirs, video_backend=backend)
    assert len(a) == len(b) == sum(LENGTHS)
    for i in (0, 9, 10, 22, len(a) - 1):
        x, y = a[i], b[i]
        assert x.keys() == y.keys()
        assert torch.equal(x["observation.image"], y["observation.image"]), i
        assert torch.equal(x["action"], y["action"])
    # our reader decodes what LeRobotDataset decodes
    frame = (a[22]["observation.image"] * 255).round().to(torch.uint8).permute(1, 2, 0).numpy()
    assert np.abs(frame.astype(int) - read_episode_frames(ours, 1)["observation.image"][12]).max() <= 1


def test_video_datasets_are_byte_deterministic(tmp_path, video_ds):
    root, summary = video_ds
    again = _write(tmp_path / "again", encode_in_background=False)
    assert again.fingerprint == summary.fingerprint == dataset_fingerprint(root)


def test_encoding_leaves_the_process_scheduling_as_it_was(tmp_path):
    """libsvtav1 makes the thread that encodes SCHED_FIFO 99 when it runs as root; hub-envs puts the policy
    back, or every process forked afterwards (rollout pools, env workers) would run real-time."""
    import os

    from hub_envs.dataset.video import encode_episode

    before = os.sched_getscheduler(0), os.sched_getparam(0)
    frames = np.random.default_rng(0).integers(0, 255, (3, 32, 32, 3), dtype=np.uint8)
    encode_episode(frames, tmp_path / "episode.mp4", 10)
    assert (os.sched_getscheduler(0), os.sched_getparam(0)) == before


def test_frames_too_small_for_the_encoder_are_refused_not_a_crash(tmp_path):
    """libsvtav1 kills the process (SIGFPE) on frames under 28 px: a typed error names the size and the fix."""
    from hub_envs.dataset.video import encode_episode

    with pytest.raises(errors.DatasetError, match=r"16x16 px .* --video=false"):
        encode_episode(np.zeros((3, 16, 16, 3), np.uint8), tmp_path / "episode.mp4", 10)


def test_small_video_files_roll_over_and_decode(tmp_path):
    """Past video_files_size_in_mb a new file starts; each episode decodes from the file its metadata names."""
    root = tmp_path / "many"
    _write(root, video_files_size_in_mb=0.000001)
    files = sorted((root / "videos/observation.image/chunk-000").glob("*.mp4"))
    assert len(files) == len(LENGTHS)
    for i, n in enumerate(LENGTHS):
        assert (
            frame_errors(read_episode_frames(root, i)["observation.image"], _frames(i, n)).max()
            <= VIDEO_TOLERANCE.max_mean_abs_error
        )


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_damaged_video_is_an_integrity_error(tmp_path, video_ds, damage):
    root = tmp_path / "ds"
    shutil.copytree(video_ds[0], root)
    path = root / "videos/observation.image/chunk-000/file-000.mp4"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3] if damage == "truncate" else data[:64] + b"\0" * (len(data) - 64))
    with pytest.raises(errors.IntegrityError) as e:
        for i in range(len(LENGTHS)):
            read_episode_frames(root, i)
    assert "file-000.mp4" in str(e.value) and "fetch" in str(e.value)
    path.unlink()
    with pytest.raises(errors.IntegrityError, match="missing"):
        read_episode_frames(root, 0)


# --- push_env --video on the reach example env ---------------------------------------------------


@pytest.fixture(scope="module")
def reach_video(hub_module, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("reach")
    folder = copy_env(
        tmp,
        ENVS / "reach",
        "reach",
        edits={"config.py": lambda s: s.replace("episode_length: int = 100", "episode_length: int = 12")},
    )
    pushed = push_env(folder, "alice/reach-video", episodes=2, progress=False)  # video: default for a camera env
    return folder, pushed


def test_push_reach_defaults_to_video_and_lerobot_decodes_it(hub_module, reach_video, tmp_path):
    from hub_envs._compat import video_backend

    _, pushed = reach_video
    features = pushed.manifest.dataset["features"]
    assert features["observation.image"]["dtype"] == "video"
    assert any(p.startswith("dataset/videos/observation.image/") and p.endswith(".mp4") for p in pushed.manifest.files)
    loaded = load_env(f"alice/reach-video@{pushed.sha}", trust_remote_code=True)
    ds = loaded.open_dataset()  # the video backend that works here
    assert ds.meta.video_keys == ["observation.image"]
    item = ds[5]
    assert tuple(item["observation.image"].shape) == (3, 96, 96) and item["observation.image"].dtype.is_floating_point
    assert video_backend() in ("pyav", "torchcodec")
    loaded.unregister()


def test_reproduce_reach_video_within_the_tolerance(hub_module, reach_video, tmp_path):
    _, pushed = reach_video
    report = reproduce(f"alice/reach-video@{pushed.sha}", trust_remote_code=True, workers=1, out=tmp_path / "out", progress=False)
    assert report.reproduced, report.summary()
    replay = report.replay
    assert "observation.image" in replay.features and replay.video["keys"] == ["observation.image"]
    worst = max(e.max_abs_diff["observation.image"] for e in replay.episodes)
    assert 0 < worst <= VIDEO_TOLERANCE.max_mean_abs_error  # lossy, within the bound
    # everything else stays exact
    for e in replay.episodes:
        assert all(v == 0.0 for k, v in e.max_abs_diff.items() if k != "observation.image"), e.max_abs_diff
    assert "env_state" in replay.features
    assert "within mean abs error" in replay.summary()
    # and beyond the tolerance: the env renders the recorded frames bit for bit (the sha256 push recorded of them)
    assert replay.video["bit_exact"] and all(e.video_exact == {"observation.image": True} for e in replay.episodes)
    assert "rendered bit for bit as recorded" in replay.summary()


def _strip_frames_sha256(dataset: Path, dest: Path) -> Path:
    """A copy of ``dataset`` as a push before the frames' sha256 were recorded wrote it (or with them edited)."""
    import pyarrow.parquet as pq

    shutil.copytree(dataset, dest)
    for path in (dest / "meta/episodes").rglob("*.parquet"):
        table = pq.read_table(path)
        pq.write_table(table.drop_columns([n for n in table.column_names if n.startswith("frames_sha256/")]), path)
    return dest


def test_replay_checks_the_rendered_frames_against_their_recorded_sha256(hub_module, reach_video, tmp_path):
    """The env renders the recorded frames bit for bit: the sha256 push recorded says so without a second
    encoder pass, and the video's keyframes, decoded, are within the tolerance of them (the file holds them);
    a camera off by one level in one pixel (far inside the codec's tolerance) still reproduces within the
    tolerance, every frame decoded, but not bit for bit; so does an edited sha256."""
    import gymnasium as gym
    import pyarrow.parquet as pq

    from hub_envs.dataset.video import DEFAULT_VIDEO_GOP
    from hub_envs.harness.replay import replay_dataset

    _, pushed = reach_video
    loaded = load_env(f"alice/reach-video@{pushed.sha}", trust_remote_code=True)
    try:
        root, fmap = loaded.dataset_root, loaded.config.features_map
        same = replay_dataset(loaded.make, root, fmap, progress=False)
        assert same.ok and same.video["bit_exact"] and same.video["bit_exact_by"] == "frames_sha256", same.summary()
        assert all(e.video_exact_by == {"observation.image": "frames_sha256"} for e in same.episodes)
        keyframes = [-(-e.length // DEFAULT_VIDEO_GOP) for e in same.episodes]  # the first frame, then every GOP-th
        assert [e.video_checked["observation.image"] for e in same.episodes] == keyframes
        assert same.video["frames_checked"] == sum(keyframes) < same.video["frames"] == sum(e.length for e in same.episodes)
        assert 0 < same.video["worst"] <= VIDEO_TOLERANCE.max_mean_abs_error

        class OneLevelOff(gym.ObservationWrapper):
            def observation(self, obs):
                pixels = obs["pixels"].copy()
                pixels[0, 0, 0] ^= 1
                return {**obs, "pixels": pixels}

        off = replay_dataset(lambda: OneLevelOff(loaded.make()), root, fmap, progress=False)
        assert off.ok, off.summary()  # within the tolerance
        assert not off.video["bit_exact"] and all(e.video_exact == {"observation.image": False} for e in off.episodes)
        assert off.video["frames_checked"] == off.video["frames"]  # not the recorded frames: every one is decoded
        assert "bit for bit" not in off.summary() and "within mean abs error" in off.summary()

        edited = tmp_path / "edited"
        shutil.copytree(root, edited)
        path = next((edited / "meta/episodes").rglob("*.parquet"))
        table = pq.read_table(path)
        column = table.column_names.index("frames_sha256/observation.image")
        table = table.set_column(column, "frames_sha256/observation.image", [["0" * 64] * table.num_rows])
        pq.write_table(table, path)
        lied = replay_dataset(loaded.make, edited, fmap, progress=False)
        assert lied.ok and not lied.video["bit_exact"], lied.summary()
    finally:
        loaded.unregister()


def test_a_video_that_does_not_hold_the_recorded_frames_diverges(hub_module, reach_video, tmp_path):
    """The recorded sha256 says what the env rendered; the video must still show it: a dataset whose MP4 holds
    other pictures (the same episodes' frames, colours inverted) beside the genuine sha256 diverges at frame 0."""
    from hub_envs.dataset.reader import read_episode_meta
    from hub_envs.harness.replay import replay_dataset

    _, pushed = reach_video
    loaded = load_env(f"alice/reach-video@{pushed.sha}", trust_remote_code=True)
    try:
        root = loaded.dataset_root
        info = read_info(root)
        features = {
            k: v
            for k, v in info["features"].items()
            if k not in ("timestamp", "frame_index", "episode_index", "index", "task_index")
        }
        inverted = [
            EpisodeFrames(
                m["episode_index"],
                m["seed"],
                {k: v for k, v in read_episode_frames(root, m["episode_index"]).items() if k in features},
            )
            for m in read_episode_meta(root)
        ]
        for ep in inverted:
            ep.frames["observation.image"] = 255 - ep.frames["observation.image"]
        other = tmp_path / "inverted"
        write_lerobot_dataset(
            other, repo_id="x/y", fps=info["fps"], features=features, episodes=inverted, task="t", progress=False
        )
        swapped = tmp_path / "swapped"
        shutil.copytree(root, swapped)
        shutil.rmtree(swapped / "videos")
        shutil.copytree(other / "videos", swapped / "videos")
        replay = replay_dataset(loaded.make, swapped, loaded.config.features_map, progress=False)
    finally:
        loaded.unregister()
    assert not replay.ok
    first = replay.first_divergence
    assert (first.episode, first.step, first.feature) == (0, 0, "observation.image"), replay.summary()
    assert first.max_abs_diff > VIDEO_TOLERANCE.max_mean_abs_error and "video frame" in first.note
    assert replay.video["bit_exact"]  # the env does render the recorded frames: the video is what is wrong


def video_panels(fig) -> list:
    """The axes of a reproduce figure that plot the video error: those with a tolerance line."""
    return [ax for ax in fig.axes if any(line.get_label().startswith("tolerance") for line in ax.get_lines())]


def test_the_reproduce_plot_shows_each_frames_video_error_against_the_tolerance(hub_module, reach_video, tmp_path, monkeypatch):
    """The one figure of a reproduction that is not exact, plotted: every replayed frame's mean abs error against
    the decoded video, over the whole replay, under the tolerance line; the Markdown states the numbers."""
    import hub_envs.harness.report

    _, pushed = reach_video
    figures = saved_figures(monkeypatch, hub_envs.harness.report)
    report = reproduce(f"alice/reach-video@{pushed.sha}", trust_remote_code=True, workers=1, out=tmp_path / "out", progress=False)
    assert report.reproduced, report.summary()
    (fig,) = figures  # what report.png was drawn from
    (ax,) = video_panels(fig)
    assert "observation.image" in ax.get_title()
    (tolerance,) = [line for line in ax.get_lines() if line.get_label().startswith("tolerance")]
    assert list(tolerance.get_ydata()) == [VIDEO_TOLERANCE.max_mean_abs_error] * 2
    (curve,) = [line for line in ax.get_lines() if len(line.get_ydata()) > 2]
    errors = np.asarray(curve.get_ydata(), dtype=float)
    assert len(errors) == sum(e.length for e in report.replay.episodes) == pushed.manifest.dataset["frames"]
    decoded = errors[~np.isnan(errors)]  # frames rendered bit for bit are not decoded: keyframes only, gaps elsewhere
    assert len(decoded) == report.replay.video["frames_checked"] and 0 < len(decoded) <= len(errors)
    worst = max(e.max_abs_diff["observation.image"] for e in report.replay.episodes)
    assert decoded.max() == pytest.approx(worst, rel=1e-6) and 0 < worst <= VIDEO_TOLERANCE.max_mean_abs_error
    assert ax.get_ylim()[0] == 0 and ax.get_ylim()[1] > VIDEO_TOLERANCE.max_mean_abs_error  # the line is in view
    assert report.replay.video["mean"] == pytest.approx(float(decoded.mean()), rel=1e-6)
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert "Video `observation.image` (lossy)" in markdown and f"at most {VIDEO_TOLERANCE.max_mean_abs_error:g}" in markdown
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    assert "video_errors" not in data["replay"]["episodes"][0]  # per-frame errors stay out of the JSON: bounded size


def test_push_video_false_stores_pngs_and_re_push_is_unchanged(hub_module, reach_video):
    folder, pushed = reach_video
    again = push_env(folder, "alice/reach-video", episodes=2, progress=False)
    assert again.sha == pushed.sha and not again.created_commit  # the fast path knows video was on
    pngs = push_env(folder, "alice/reach-video", episodes=2, progress=False, video=False)
    assert pngs.created_commit and pngs.manifest.dataset["features"]["observation.image"]["dtype"] == "image"
    assert not any(p.startswith("dataset/videos/") for p in pngs.manifest.files)


def test_the_videos_gop_is_recorded_and_replay_re_encodes_with_it(hub_module, reach_video, tmp_path):
    """push_env's keyframe interval (default DEFAULT_VIDEO_GOP, ``video_gop=2`` for LeRobot's) is in the manifest
    and in info.json as LeRobot reads it (``video.g``); a re-push with another GOP is a new commit, and replay of a
    dataset without the frames' sha256 (pushed before they were recorded) re-encodes with the dataset's own GOP
    (else the bit-exact re-encode check could not hold)."""
    from hub_envs._compat import video_gop
    from hub_envs.dataset.video import DEFAULT_VIDEO_GOP
    from hub_envs.harness.replay import replay_dataset

    folder, pushed = reach_video
    api = hub_module.api

    def recorded(repo: str, sha: str) -> int:
        info = json.loads(Path(api.hf_hub_download(repo, "dataset/meta/info.json", revision=sha)).read_text())
        return video_gop(info["features"]["observation.image"]["info"])

    assert pushed.manifest.dataset["video_gop"] == DEFAULT_VIDEO_GOP == recorded("alice/reach-video", pushed.sha) != 2
    lerobots = push_env(folder, "alice/reach-gop2", episodes=2, progress=False, video_gop=2)
    assert lerobots.manifest.dataset["video_gop"] == 2 == recorded("alice/reach-gop2", lerobots.sha)
    report = reproduce(
        f"alice/reach-gop2@{lerobots.sha}", trust_remote_code=True, workers=1, out=tmp_path / "out", progress=False
    )
    assert report.reproduced and report.replay.video["bit_exact"], report.summary()
    loaded = load_env(f"alice/reach-gop2@{lerobots.sha}", trust_remote_code=True)
    try:
        older = _strip_frames_sha256(loaded.dataset_root, tmp_path / "no-sha256")
        replay = replay_dataset(loaded.make, older, loaded.config.features_map, progress=False)
    finally:
        loaded.unregister()
    assert replay.ok and replay.video["bit_exact"] and replay.video["bit_exact_by"] == "reencode", replay.summary()
    assert "re-encoded, bit for bit" in replay.summary()
    again = push_env(folder, "alice/reach-gop2", episodes=2, progress=False)  # the default GOP: not what main holds
    assert again.created_commit and again.manifest.dataset["video_gop"] == DEFAULT_VIDEO_GOP
    with pytest.raises(errors.ConfigError, match="video_gop"):
        push_env(folder, "alice/reach-gop2", episodes=2, progress=False, video_gop=0)


def test_truncated_video_in_a_published_repo_is_refused(hub_module, reach_video, tmp_path):
    """A commit that truncates the MP4 (the manifest not fixed up) is refused when the data is fetched."""
    _, pushed = reach_video
    api = hub_module.api
    mp4 = next(p for p in pushed.manifest.files if p.endswith(".mp4"))
    data = Path(api.hf_hub_download("alice/reach-video", mp4, revision=pushed.sha)).read_bytes()
    api.create_branch("alice/reach-video", branch="cut", revision=pushed.sha)
    commit = api.upload_file(
        path_or_fileobj=data[: len(data) // 2], path_in_repo=mp4, repo_id="alice/reach-video", revision="cut"
    )
    loaded = load_env(f"alice/reach-video@{commit.oid}", trust_remote_code=True)
    with pytest.raises(errors.IntegrityError) as e:
        loaded.open_dataset()
    assert mp4.split("/")[-1] in str(e.value)
    loaded.unregister()


def test_card_media_is_big_real_time_and_has_an_mp4(hub_module, reach_video):
    """The GIF is >= 256 px wide as rendered by the env (reach's render_width knob, not an upscale), shows
    the first episodes (up to 3) at the env's real speed, stays small; the MP4 sits beside it; card and page show both."""
    import av
    import imageio.v3 as iio
    import requests

    _, pushed = reach_video
    api = hub_module.api
    gif_path = api.hf_hub_download("alice/reach-video", "media/rollout.gif", revision=pushed.sha)
    frames = iio.imread(gif_path, index=None)
    assert frames.shape[1:3] == (256, 256)
    # the first 3 dataset episodes (this push has 2) of 12 steps, every 2nd step (20 fps -> 10 frames per second)
    assert len(frames) == 2 * 12 // 2
    assert iio.immeta(gif_path)["duration"] == 100  # ms per frame: real time
    assert Path(gif_path).stat().st_size < 3 * 2**20
    # rendered, not repeated pixels: neighbouring columns differ somewhere (a 3x upscale of 96 px would not)
    assert (frames[:, :, 0:255:3] != frames[:, :, 1:256:3]).any()
    assert "media/rollout.mp4" in pushed.manifest.files
    with av.open(api.hf_hub_download("alice/reach-video", "media/rollout.mp4", revision=pushed.sha)) as mp4:
        stream = mp4.streams.video[0]
        assert (stream.width, stream.height, int(stream.base_rate)) == (256, 256, 10)
    card = Path(api.hf_hub_download("alice/reach-video", "README.md", revision=pushed.sha)).read_text()
    assert "](media/rollout.gif)" in card and "](media/rollout.mp4)" in card and "real time (20 fps)" in card
    page = requests.get(
        f"{hub_module.endpoint}/alice/reach-video/tree/{pushed.sha}", headers={"Accept": "text/html"}, timeout=30
    ).text
    assert f'<video src="/alice/reach-video/resolve/{pushed.sha}/media/rollout.mp4"' in page
