"""The helper process that PNG-encodes camera episodes while the next ones are made: the same files as encoding
inline; nothing left behind however the dataset or either process ends; a forked process (a pool worker, a helper)
neither uses nor ends its parent's helper."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from hub_envs.dataset import png_process
from hub_envs.dataset.codec import decode_png, encode_png
from hub_envs.dataset.reader import read_episode_frames
from hub_envs.dataset.stats import image_stats
from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset
from hub_envs.errors import DatasetError

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FEATURES = {
    "observation.image": {"dtype": "image", "shape": [16, 24, 3], "names": ["height", "width", "channels"]},
    "action": {"dtype": "float32", "shape": [1], "names": ["u"]},
}

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the helper needs fork and memfd (Linux)")


def _episodes(n: int, length: int = 30, fail_at: int | None = None, on_episode=None):
    rng = np.random.default_rng(0)
    for i in range(n):
        if i == fail_at:
            raise RuntimeError("the env broke")
        if on_episode is not None:
            on_episode(i)
        frames = rng.integers(0, 256, (length + i, 16, 24, 3), dtype=np.uint8)
        actions = rng.normal(size=(length + i, 1)).astype(np.float32)
        yield EpisodeFrames(i, seed=i, frames={"observation.image": frames, "action": actions})


def _write(root, episodes, background: bool = True):
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


def _alive(pid: int) -> bool:
    try:
        return os.waitpid(pid, os.WNOHANG)[0] == 0
    except ChildProcessError:
        return False


def _idle_pid() -> int:
    helper = png_process.acquire()
    png_process.release(helper, ok=True)
    return helper.pid


def test_the_files_are_those_of_encoding_inline_and_the_frames_decode_exactly(tmp_path):
    inline = _write(tmp_path / "inline", _episodes(5), background=False)
    helped = _write(tmp_path / "helped", _episodes(5))
    again = _write(tmp_path / "again", _episodes(5))  # the idle helper, its slots reused
    assert inline.fingerprint == helped.fingerprint == again.fingerprint
    frames = read_episode_frames(tmp_path / "helped", 4)["observation.image"]
    np.testing.assert_array_equal(frames, list(_episodes(5))[4].frames["observation.image"])
    assert not [f for f in os.listdir("/dev/shm") if f.startswith(f"hub-envs-png-{os.getpid()}-")]  # memfds: no names


def test_slots_grow_for_a_bigger_episode_and_are_reused_for_a_smaller_one():
    helper = png_process.acquire()
    try:
        for length in (3, 50, 7, 120, 2):
            frames = np.random.default_rng(length).integers(0, 256, (length, 8, 8, 4), dtype=np.uint8)
            gray = np.ascontiguousarray(frames[..., :1])
            helper.submit([frames, gray])
            (pngs, stats), (gray_pngs, _) = helper.result()
            assert pngs == encode_png(frames) and gray_pngs == encode_png(gray)
            expected = image_stats(frames)
            assert stats.keys() == expected.keys() and all(np.array_equal(stats[k], v) for k, v in expected.items())
            np.testing.assert_array_equal(decode_png(pngs[-1]), frames[-1])
    finally:
        png_process.release(helper, ok=True)


def test_a_failing_episode_source_leaves_no_dataset_and_ends_the_busy_helper(tmp_path):
    pids = []
    with pytest.raises(DatasetError, match="the env broke"):
        _write(tmp_path / "ds", _episodes(6, fail_at=4, on_episode=lambda i: pids.append(_busy_pid())))
    assert not list(tmp_path.iterdir())
    assert not _alive(pids[-1]) and pids[-1] not in {h.pid for h in png_process._IDLE}


def test_a_helper_killed_mid_dataset_is_a_dataset_error_naming_it_and_the_next_dataset_is_written(tmp_path):
    def kill_at_3(i):
        if i == 3:
            os.kill(_busy_pid(), signal.SIGKILL)

    with pytest.raises(DatasetError, match="PNG encoding process (stopped|is gone)"):
        _write(tmp_path / "ds", _episodes(6, on_episode=kill_at_3))
    assert not (tmp_path / "ds").exists()
    assert _write(tmp_path / "next", _episodes(3)).episodes == 3


def test_an_idle_helper_holds_no_slot_memory_after_a_big_dataset_and_no_inherited_files(tmp_path, monkeypatch):
    import socket

    listening = socket.create_server(("127.0.0.1", 0))  # a parent's socket: it must not stay open in the helper
    try:
        png_process._close_idle()  # the next helper is forked now, with the socket open
        monkeypatch.setattr(png_process, "_KEEP_SLOTS_BYTES", 0)  # every dataset counts as big
        _write(tmp_path / "ds", _episodes(3))
        pid = _idle_pid()
        maps = open(f"/proc/{pid}/maps").read()
        assert "hub-envs-png-slot" not in maps
        fds = {os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")}
        assert not any("socket" in fd for fd in fds - {_helper_socket(pid)}), fds
    finally:
        listening.close()


def test_a_pool_worker_writes_a_dataset_with_a_helper_and_the_parents_helper_survives_forked_children(tmp_path):
    """A daemonic multiprocessing worker can have a helper; a child forked from a process with an idle helper, exiting
    normally (its atexit handlers run), leaves that helper alone; the parent then uses it again."""
    script = textwrap.dedent(
        f"""
        import multiprocessing, os, sys
        sys.path.insert(0, {REPO!r})
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        from test_png_process import _write, _episodes, _idle_pid

        def in_worker(root):
            return _write(root, _episodes(3)).fingerprint

        if __name__ == "__main__":
            root = {str(tmp_path)!r}
            ctx = multiprocessing.get_context("fork")
            with ctx.Pool(1) as pool:
                in_pool = pool.apply(in_worker, (root + "/pool",))
            mine = _write(root + "/mine", _episodes(3)).fingerprint
            helper = _idle_pid()
            pid = os.fork()
            if pid == 0:
                sys.exit(0)  # a normal exit: interpreter shutdown and atexit handlers run
            os.waitpid(pid, 0)
            assert _idle_pid() == helper, "the forked child's exit ended the parent's helper"
            assert _write(root + "/again", _episodes(3)).fingerprint == mine == in_pool
            print("ok")
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-3000:]


def test_a_helper_ends_when_its_parent_is_killed(tmp_path):
    script = textwrap.dedent(
        f"""
        import sys, time
        sys.path.insert(0, {REPO!r})
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        from test_png_process import _write, _episodes, _idle_pid
        _write({str(tmp_path / "ds")!r}, _episodes(2))
        print(_idle_pid(), flush=True)
        time.sleep(60)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    helper = int(proc.stdout.readline())
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 10
    while os.path.exists(f"/proc/{helper}") and time.monotonic() < deadline:
        with open(f"/proc/{helper}/stat") as f:  # reparented: a zombie until its new parent reaps it
            if f.read().split(") ")[1].startswith("Z"):
                break
        time.sleep(0.1)
    assert time.monotonic() < deadline, "the helper outlived its killed parent"


def _busy_pid() -> int:
    """The pid of this process's helper that is not idle (the one a dataset is being written with)."""
    idle = {h.pid for h in png_process._IDLE}
    mine = os.getpid()
    children = []
    for pid in os.listdir("/proc"):
        if pid.isdigit() and int(pid) not in idle:
            try:
                with open(f"/proc/{pid}/stat") as f:
                    fields = f.read().rsplit(") ", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == mine and fields[0] != "Z":
                children.append(int(pid))
    busy = [pid for pid in children if "hub-envs-png-slot" in open(f"/proc/{pid}/maps").read()]
    assert len(busy) == 1, (children, busy)
    return busy[0]


def _helper_socket(pid: int) -> str:
    """The helper's end of its socket pair (the one socket it keeps)."""
    return next(os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd") if fd not in ("0", "1", "2"))


def test_an_idle_helper_ends_itself_and_the_next_dataset_gets_a_new_one(tmp_path, monkeypatch):
    """An idle helper holds a copy of this process's memory as it was when forked: it does not stay for ever."""
    png_process._close_idle()
    monkeypatch.setattr(png_process, "IDLE_SECONDS", 1.0)  # read by the helper forked next
    _write(tmp_path / "a", _episodes(2))
    old = png_process._IDLE[0]
    deadline = time.monotonic() + 10
    while old.alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not old.alive() and old.exitcode == 0
    assert _write(tmp_path / "b", _episodes(2)).episodes == 2 and png_process._IDLE[0] is not old


def test_a_slow_env_between_episodes_does_not_end_the_helper_mid_dataset(tmp_path, monkeypatch):
    """Only a released helper counts down: episodes slower than IDLE_SECONDS to make still get their frames encoded."""
    png_process._close_idle()
    monkeypatch.setattr(png_process, "IDLE_SECONDS", 1.0)
    summary = _write(tmp_path / "slow", _episodes(4, on_episode=lambda i: time.sleep(2.5 if i == 2 else 0)))
    assert summary.fingerprint == _write(tmp_path / "inline", _episodes(4), background=False).fingerprint


def test_a_process_forked_mid_dataset_holds_none_of_the_helpers_slots(tmp_path):
    """A pool or vector env started from the episode generator must not keep two episodes of frames mapped."""
    seen = []

    def fork_at_2(i):
        if i == 2:
            read, write = os.pipe()
            pid = os.fork()
            if pid == 0:  # pragma: no cover - reports through the pipe
                try:
                    os.write(write, b"1" if "hub-envs-png-slot" in open("/proc/self/maps").read() else b"0")
                finally:
                    os._exit(0)
            os.close(write)
            os.waitpid(pid, 0)
            seen.append(os.read(read, 1))
            os.close(read)

    _write(tmp_path / "ds", _episodes(4, on_episode=fork_at_2))
    assert seen == [b"0"]


def test_the_helper_does_not_run_the_parents_signal_handlers(tmp_path):
    """A SIGTERM to the process group (Slurm, systemd, kill -- -PGID) runs the application's cleanup once, in it."""
    log = tmp_path / "ran"
    script = textwrap.dedent(
        f"""
        import os, signal, sys, time
        sys.path.insert(0, {REPO!r})
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        from test_png_process import _write, _episodes, _idle_pid

        def cleanup(*_):
            with open({str(log)!r}, "a") as f:
                f.write(f"{{os.getpid()}}\\n")
            os._exit(0)

        signal.signal(signal.SIGTERM, cleanup)
        _write({str(tmp_path / "ds")!r}, _episodes(2))
        print(os.getpid(), _idle_pid(), flush=True)
        os.killpg(os.getpgid(0), signal.SIGTERM)  # its own session (start_new_session): this process and the helper
        time.sleep(5)
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, start_new_session=True)
    parent, helper = proc.stdout.split()
    assert log.read_text().split() == [parent], (log.read_text(), helper, proc.stderr[-2000:])
