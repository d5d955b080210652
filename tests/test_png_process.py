"""The helper process that PNG-encodes camera episodes while the next ones are made: same files as encoding inline,
nothing left behind when it fails or is stopped, a forked process never uses its parent's helper."""

from __future__ import annotations

import glob
import os
import signal

import numpy as np
import pytest

from hub_envs.dataset import png_process
from hub_envs.dataset.codec import decode_png, encode_png
from hub_envs.dataset.reader import read_episode_frames
from hub_envs.dataset.stats import image_stats
from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset
from hub_envs.errors import DatasetError

FEATURES = {
    "observation.image": {"dtype": "image", "shape": [16, 24, 3], "names": ["height", "width", "channels"]},
    "action": {"dtype": "float32", "shape": [1], "names": ["u"]},
}


def _episodes(n: int, length: int = 30, fail_at: int | None = None):
    rng = np.random.default_rng(0)
    for i in range(n):
        if i == fail_at:
            raise RuntimeError("the env broke")
        frames = rng.integers(0, 256, (length + i, 16, 24, 3), dtype=np.uint8)
        yield EpisodeFrames(
            i, seed=i, frames={"observation.image": frames, "action": rng.normal(size=(length + i, 1)).astype(np.float32)}
        )


def _shm_files() -> list[str]:
    return glob.glob(f"/dev/shm/hub-envs-png-{os.getpid()}-*")


def _write(root, episodes, background: bool):
    return write_lerobot_dataset(
        root,
        repo_id="t/png",
        fps=10,
        features=FEATURES,
        episodes=episodes,
        task="t",
        progress=False,
        encode_in_background=background,
    )


def _helper_runs_here() -> bool:
    helper = png_process.acquire()
    if helper is not None:
        png_process.release(helper, ok=True)
    return helper is not None


@pytest.mark.skipif(not _helper_runs_here(), reason="no fork or /dev/shm here: the writer encodes on a thread")
class TestHelper:
    def test_the_files_are_those_of_encoding_inline_and_the_frames_decode_exactly(self, tmp_path):
        inline = _write(tmp_path / "inline", _episodes(5), background=False)
        helped = _write(tmp_path / "helped", _episodes(5), background=True)
        again = _write(tmp_path / "again", _episodes(5), background=True)  # the idle helper, its slots reused
        assert inline.fingerprint == helped.fingerprint == again.fingerprint
        frames = read_episode_frames(tmp_path / "helped", 4)["observation.image"]
        np.testing.assert_array_equal(frames, list(_episodes(5))[4].frames["observation.image"])

    def test_an_episode_bigger_than_the_slots_grows_them_and_a_smaller_one_reuses_them(self):
        helper = png_process.acquire()
        try:
            for length in (3, 50, 7, 120, 2):
                frames = np.random.default_rng(length).integers(0, 256, (length, 8, 8, 4), dtype=np.uint8)
                helper.submit([frames, frames[:, :, :, :1].copy()])
                (pngs, stats), (gray, _) = helper.result()
                assert pngs == encode_png(frames) and gray == encode_png(frames[:, :, :, :1].copy())
                assert stats.keys() == image_stats(frames).keys()
                assert all(np.array_equal(stats[k], v) for k, v in image_stats(frames).items())
                np.testing.assert_array_equal(decode_png(pngs[-1]), frames[-1])
        finally:
            png_process.release(helper, ok=True)

    def test_a_failing_episode_source_leaves_no_dataset_and_no_helper_or_files(self, tmp_path):
        before = {h.process.pid for h in png_process._IDLE}
        with pytest.raises(DatasetError, match="the env broke"):
            _write(tmp_path / "ds", _episodes(6, fail_at=4), background=True)
        assert not (tmp_path / "ds").exists() and not list(tmp_path.iterdir())
        busy = [h for h in png_process._IDLE if h.process.pid not in before]
        assert not busy  # the helper that held episodes was ended, not kept
        assert len(_shm_files()) <= 2 * len(png_process._IDLE)  # only an idle helper's slots remain

    def test_a_helper_killed_mid_dataset_is_a_dataset_error_and_the_next_dataset_is_written(self, tmp_path):
        def killing():
            for ep in _episodes(6):
                if ep.index == 3:
                    os.kill(_busy_helper_pid(), signal.SIGKILL)
                yield ep

        with pytest.raises(DatasetError, match="PNG encoding process stopped"):
            _write(tmp_path / "ds", killing(), background=True)
        assert not (tmp_path / "ds").exists()
        summary = _write(tmp_path / "next", _episodes(3), background=True)
        assert summary.episodes == 3

    def test_a_forked_process_starts_its_own_helper_not_its_parents(self):
        helper = png_process.acquire()
        png_process.release(helper, ok=True)
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child reports through the pipe
            try:
                mine = png_process.acquire()
                ok = mine is not helper and mine.owner == os.getpid()
                frames = np.zeros((2, 4, 4, 3), np.uint8)
                mine.submit([frames])
                ok = ok and mine.result()[0][0] == encode_png(frames)
                png_process.release(mine, ok=False)
                os.write(write, b"1" if ok else b"0")
            finally:
                os._exit(0)
        os.close(write)
        os.waitpid(pid, 0)
        assert os.read(read, 1) == b"1"
        assert helper.process.is_alive() and png_process.acquire() is helper  # the parent's helper untouched
        png_process.release(helper, ok=True)


def _busy_helper_pid() -> int:
    """The pid of the helper a dataset is being written with: this process's child named hub-envs-png, not idle."""
    import multiprocessing

    idle = {h.process.pid for h in png_process._IDLE}
    pids = [p.pid for p in multiprocessing.active_children() if p.name == "hub-envs-png" and p.pid not in idle]
    assert len(pids) == 1, pids
    return pids[0]
