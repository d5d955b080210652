"""Isolated envs (``load_env(..., isolation="process")``): real worker processes, the real loopback Hub.

The example envs are pushed once per module; each test loads them in-process and isolated and holds the
proxy to the in-process env bit for bit (single envs and ``make_vec``). A hostile env
(``tests/fixtures/hostile_env``: behaves until ``reset(options={"mode": ...})`` arms an attack) checks
that every fault is typed and contained: the env raising, a segfault, a hang, and that no worker outlives
its env or its parent.
"""

from __future__ import annotations

import json
import os
import platform
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from helpers import FIXTURES

from hub_envs import errors, load_env, push_env
from hub_envs.isolation.proxy import IsolatedEnv

ENVS = Path(__file__).resolve().parents[1] / "envs"
HOSTILE = FIXTURES / "hostile_env"


@pytest.fixture(scope="module")
def published(hub_module):
    """repo@sha of the three example envs and the hostile env on one loopback Hub."""
    out = {}
    for name, folder in (
        ("pendulum", ENVS / "pendulum"),
        ("hover", ENVS / "hover"),
        ("reach", ENVS / "reach"),
        ("hostile", HOSTILE),
    ):
        result = push_env(folder, f"iso/{name}", episodes=1, progress=False, workers=1)
        out[name] = f"iso/{name}@{result.sha}"
    return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is dead too
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def _wait_gone(pid: int, seconds: float = 10.0) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if not _alive(pid):
            return True
        time.sleep(0.05)
    return False


def _rollout(env, seed: int, steps: int) -> list:
    env.action_space.seed(seed)
    out = [env.reset(seed=seed)]
    for _ in range(steps):
        step = env.step(env.action_space.sample())
        out.append(step)
        if step[2] or step[3]:
            out.append(env.reset())
    out.append(env.render())
    return out


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)):
        return isinstance(b, (tuple, list)) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    return type(a) is type(b) and a == b


def _inner(env) -> IsolatedEnv:
    assert isinstance(env.unwrapped, IsolatedEnv), env
    return env.unwrapped


@pytest.mark.parametrize("name", ["pendulum", "hover", "reach"])
def test_an_isolated_env_steps_bit_identically_to_the_in_process_env(published, name):
    ref = published[name]
    here = load_env(ref, trust_remote_code=True)
    isolated = load_env(ref, trust_remote_code=True, isolation="process", check=(name == "pendulum"))
    assert isolated.gym_id != here.gym_id and isolated.isolation is not None
    if name == "pendulum":  # the feature check and the golden-rollout fingerprint ran through the proxy
        assert isolated.report.fingerprint.startswith("matches")
    a, b = here.make(max_episode_steps=15), gym.make(isolated.gym_id, max_episode_steps=15)
    try:
        worker = _inner(b).worker
        assert worker.pid != os.getpid() and worker.start_seconds > 0
        assert b.observation_space == a.observation_space and b.action_space == a.action_space
        assert b.spec.max_episode_steps == a.spec.max_episode_steps == 15
        assert b.metadata == a.metadata and b.render_mode == a.render_mode
        ra, rb = _rollout(a, 3, 20), _rollout(b, 3, 20)  # crosses the TimeLimit: truncated, then reset
        assert _same(ra, rb)
        assert any(step[3] for step in rb[1:-1] if len(step) == 5)
        # get_state / reset_to through the proxy restore a step exactly, as in-process
        assert hasattr(b.unwrapped, "get_state") and hasattr(b.unwrapped, "reset_to")
        state = b.unwrapped.get_state()
        assert _same(state, a.unwrapped.get_state())
        action = np.asarray(b.action_space.sample())
        first = b.step(action)
        b.unwrapped.reset_to(state)
        assert _same(b.step(action), first)
    finally:
        a.close()
        b.close()
    assert _wait_gone(worker.pid), "closing the env left its worker running"
    here.unregister()
    isolated.unregister()


@pytest.mark.parametrize("per_worker", [2, 0, "0 on 4 CPUs"])
def test_make_vec_isolated_matches_sync_vector_env(published, per_worker, monkeypatch):
    """Three workers of 2 + 2 + 1 envs (more workers than CPUs: each side sleeps between messages), and the default
    (a CPU kept for the caller, the others for workers: both sides busy-wait; on a machine said to have 4 CPUs,
    three busy-waiting workers) give SyncVectorEnv's answers exactly."""
    import hub_envs.isolation.vector as vector

    if per_worker == "0 on 4 CPUs":
        monkeypatch.setattr(vector, "available_cpus", lambda: 4)
        per_worker = 0
    ref = published["pendulum"]
    here = load_env(ref, trust_remote_code=True)
    isolated = load_env(ref, trust_remote_code=True, isolation="process", check=False, envs_per_worker=per_worker)
    a = here.make_vec(5, max_episode_steps=7)
    b = isolated.make_vec(5, max_episode_steps=7)
    try:
        cpus = vector.available_cpus()
        expected = 3 if per_worker else min(5, max(1, cpus - 1))
        # busy-waiting is on for each (how long it waits adapts to the answers' usual delay: Worker.spins)
        assert len(b.workers) == expected and all(w._spin.active == (expected < cpus and cpus > 1) for w in b.workers)
        assert b.single_observation_space == a.single_observation_space and b.action_space == a.action_space
        assert _same(b.reset(seed=11), a.reset(seed=11))
        b.action_space.seed(4)
        for _ in range(18):  # two autoresets (next-step mode)
            actions = b.action_space.sample()
            assert _same(b.step(actions), a.step(actions))
        assert _same(b.render(), a.render())
        pids = [w.pid for w in b.workers]
    finally:
        a.close()
        b.close()
    assert all(_wait_gone(p) for p in pids)
    here.unregister()
    isolated.unregister()


#: The hostile env's step timeout: short, for its hang cases, but not so short that a step of a loaded machine's
#: other cases (2 s was: load average 11 on 2 CPUs) trips it.
STEP_TIMEOUT = 5


@pytest.fixture(scope="module")
def hostile(published):
    return load_env(
        published["hostile"], trust_remote_code=True, isolation="process", check=False, step_timeout=STEP_TIMEOUT, restart=True
    )


def test_the_envs_own_error_comes_back_with_its_remote_traceback(hostile):
    env = hostile.make()
    try:
        assert not hasattr(env.unwrapped, "get_state") and not hasattr(env.unwrapped, "reset_to")  # as the env itself
        env.reset(seed=0, options={"mode": "raise"})
        with pytest.raises(ValueError, match="refuses this action") as info:
            env.step(env.action_space.sample())
        assert isinstance(info.value, errors.RemoteEnvError) and isinstance(info.value, errors.HubEnvsError)
        assert hostile.repo_id in str(info.value) and "hostile.py" in info.value.remote_traceback
        assert "the env refuses this action" in str(info.value.__cause__)
        # the worker lives on
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()


def test_a_segfault_is_an_env_crashed_error_and_restart_starts_a_fresh_worker(hostile):
    env = hostile.make()
    try:
        env.reset(seed=0, options={"mode": "segfault"})
        first = _inner(env).worker.pid
        with pytest.raises(errors.EnvCrashedError) as info:
            env.step(env.action_space.sample())
        message = str(info.value)
        assert hostile.repo_id in message and hostile.revision in message and "SIGSEGV" in message
        assert "about to run segfault" in message  # the last lines of the worker's stderr
        with pytest.raises(errors.EnvCrashedError):  # stepping a dead env says so again
            env.step(env.action_space.sample())
        obs, _ = env.reset(seed=1)  # restart=True: a fresh worker
        assert _inner(env).worker.pid != first and env.observation_space.contains(obs)
        env.step(env.action_space.sample())
    finally:
        env.close()


def test_a_hang_is_an_env_timeout_error_and_the_worker_is_killed(hostile):
    env = hostile.make()
    try:
        env.reset(seed=0, options={"mode": "hang"})
        pid = _inner(env).worker.pid
        t = time.perf_counter()
        with pytest.raises(errors.EnvTimeoutError, match=f"step_timeout={STEP_TIMEOUT}") as info:
            env.step(env.action_space.sample())
        assert time.perf_counter() - t < 15 and isinstance(info.value, TimeoutError)
        assert _wait_gone(pid)
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()


@pytest.mark.parametrize(
    ("attack", "said"),
    [
        ("huge", "32768"),
        ("junk", "not one"),
        ("forged", "not one"),
        ("forged-junk", "not one"),
        ("forged-tuple", "not one"),
        ("recipe", "asks for an array of 100,000,000,000 bytes"),
        ("pickled", "not one"),
    ],
)
def test_a_worker_writing_the_shared_page_gets_its_worker_stopped(hostile, attack, said):
    """The answers of a single env travel in a page the worker shares with the parent (hub_envs.isolation.doorbell):
    env code announcing an answer longer than the page, writing one that is no message, forging a fast step answer
    whose info is a pickle (code) or no message, an answer that is not a step's, 25 bytes asking the parent for a 100 GB
    array, or a pickle that would build 100 GB is stopped with EnvCrashedError (never a parent reading past the page,
    running a pickle or allocating what it was told), and the next reset starts afresh."""
    env = hostile.make()
    try:
        env.reset(seed=0, options={"mode": "page", "arg": attack})
        worker = _inner(env).worker
        with pytest.raises(errors.EnvCrashedError, match=said):
            env.step(env.action_space.sample())
        assert "found 1 doorbell(s)" in worker.stderr_tail()
        assert _wait_gone(worker.pid)
        obs, _ = env.reset(seed=0)  # restart=True: a fresh worker (and page), stepping normally
        assert env.step(env.action_space.sample())[0]["agent_pos"].shape == obs["agent_pos"].shape
    finally:
        env.close()


def test_what_the_wire_cannot_carry_is_the_envs_type_error_naming_where_it_is(hostile):
    """A worker's answers are data (hub_envs.isolation.wire), never pickles: an info holding a value outside the wire's
    kinds is a TypeError naming it, an exception whose argument is an IntEnum comes back as the env's own exception
    type, an answer that would build far more objects than it weighs is refused before it is built (each time the
    worker lives on), and a metadata entry the wire cannot carry is left out with a warning."""
    with pytest.warns(UserWarning, match="metadata entries 'hook'"):
        env = hostile.make()
    try:
        assert "hook" not in env.metadata and env.metadata["render_fps"] == 10
        pid = _inner(env).worker.pid
        env.reset(seed=0, options={"mode": "unsendable"})
        with pytest.raises(
            TypeError, match=r"the env's step returned something that cannot be sent: info\['callback'\] is of type"
        ):
            env.step(env.action_space.sample())
        assert _inner(env).worker.pid == pid
        env.reset(seed=0, options={"mode": "enum-error"})  # an exception whose argument is not plain data
        with pytest.raises(KeyError, match="Axis.Y|<Axis.Y: 2>|'2'|2"):
            env.step(env.action_space.sample())
        env.reset(seed=0, options={"mode": "many-dicts"})  # plain data, but 1.5 million dicts: refused, not built
        with pytest.raises(errors.AnswerTooLargeError, match="numpy arrays rather than many small dicts"):
            env.step(env.action_space.sample())
        assert _inner(env).worker.pid == pid  # neither stopped the worker
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()


def test_an_isolated_step_returns_none_when_the_env_returns_none(hostile):
    """The observation travels in shared memory when it can; an env whose step returns None gets None back (not the
    last observation left in shared memory)."""
    env = hostile.make()
    try:
        env.reset(seed=0)
        env.step(env.action_space.sample())
        env.reset(seed=0, options={"mode": "none-obs"})
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert obs is None and (reward, terminated, truncated, info) == (0.0, False, False, {"is_success": False})
        obs, *_ = env.step(env.action_space.sample())
        assert obs["agent_pos"].shape == (2,) and obs["agent_pos"].dtype == np.float32
    finally:
        env.close()


def test_shared_observation_buffers_give_back_exactly_what_was_written():
    """What travels through shared memory comes back as it went: a 0-d array stays an array (not a numpy scalar),
    dict keys keep their order; anything else (another order, dtype or shape) is refused, to travel in the answer."""
    from gymnasium import spaces

    from hub_envs.isolation.buffers import ObservationBuffers, box_leaves

    scalar = ObservationBuffers(box_leaves(spaces.Box(0.0, 1.0, (), np.float32)), 1)
    nested_space = spaces.Dict(
        {"a": spaces.Box(0, 1, (2,), np.float32), "b": spaces.Dict({"c": spaces.Box(0, 9, (3,), np.int64)})}
    )
    nested = ObservationBuffers(box_leaves(nested_space), 1)
    try:
        assert scalar.write_exact(0, np.array(0.5, np.float32))
        back = scalar.read_one()
        assert type(back) is np.ndarray and back.shape == () and back == np.float32(0.5)
        assert not scalar.write_exact(0, np.float32(0.5)) and not scalar.write_exact(0, np.array(0.5))
        obs = {"a": np.array([0.25, 0.5], np.float32), "b": {"c": np.array([1, 2, 3])}}
        assert nested.write_exact(0, obs)
        back = nested.read_one()
        assert list(back) == ["a", "b"] and np.array_equal(back["b"]["c"], obs["b"]["c"])
        assert not nested.write_exact(0, {"b": obs["b"], "a": obs["a"]})  # another key order: in the answer instead
        assert not nested.write_exact(0, {"a": obs["a"], "b": {"c": obs["b"]["c"].astype(np.int32)}})
    finally:
        scalar.close()
        nested.close()


def test_a_worker_that_wakes_the_parent_without_answering_still_meets_the_watchdog(hostile):
    """Env code that writes the parent's wake-up socket as fast as it can (so that its sleep keeps ending) and never
    answers is stopped by step_timeout like any hang."""
    env = hostile.make()
    try:
        env.reset(seed=0, options={"mode": "page", "arg": "wake"})
        worker = _inner(env).worker
        t = time.perf_counter()
        with pytest.raises(errors.EnvTimeoutError, match=f"step_timeout={STEP_TIMEOUT}"):
            env.step(env.action_space.sample())
        assert time.perf_counter() - t < 15
        assert "found 1 doorbell(s)" in worker.stderr_tail()
        assert _wait_gone(worker.pid)
    finally:
        env.close()


def test_a_worker_that_sends_half_an_answer_still_meets_the_watchdog(hostile):
    """Env code can write to its worker's socket: the start of a message followed by nothing is a timeout like
    any hang (the parent reads a message whole by the deadline), never a parent blocked for good."""
    import threading

    env = hostile.make()
    outcome: list = []

    def step() -> None:
        try:
            env.step(env.action_space.sample())
        except BaseException as e:
            outcome.append(e)

    try:
        env.reset(seed=0, options={"mode": "partial"})
        pid = _inner(env).worker.pid
        thread = threading.Thread(target=step, daemon=True)
        thread.start()
        thread.join(20)
        if thread.is_alive():  # the parent is stuck in a read: kill the worker so that the test can end
            os.kill(pid, signal.SIGKILL)
            thread.join(10)
            pytest.fail(f"a worker that sent half a message blocked the parent past step_timeout={STEP_TIMEOUT}")
        assert len(outcome) == 1 and isinstance(outcome[0], errors.EnvTimeoutError), outcome
        assert f"step_timeout={STEP_TIMEOUT}" in str(outcome[0])
        assert _wait_gone(pid)
    finally:
        env.close()


def test_a_worker_announcing_a_huge_answer_is_stopped_before_anything_is_read(hostile):
    """A length header over MAX_MESSAGE_BYTES (1 GiB) stops the worker at once (no watchdog wait, no memory
    spent reading): EnvCrashedError naming the size."""
    env = hostile.make()
    try:
        env.reset(seed=0, options={"mode": "huge"})
        pid = _inner(env).worker.pid
        with pytest.raises(errors.EnvCrashedError, match=f"{1 << 40} bytes"):  # not EnvTimeoutError: the header decided
            env.step(env.action_space.sample())
        assert _wait_gone(pid)
    finally:
        env.close()


@pytest.fixture
def ctrl_c():
    """SIGINT raises KeyboardInterrupt, as in an interactive Python: a test run started in the background of a
    non-interactive shell (as CI's legs are) inherits SIGINT ignored, and Python then leaves it ignored."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_during_a_step_stops_the_worker_so_no_answer_comes_out_of_step(hostile, ctrl_c):
    """A KeyboardInterrupt while the parent waits for a step: the worker is stopped (its late answer would be
    read as the answer to the next call), the next call says so, and with restart=True reset() goes on."""
    import threading

    env = hostile.make()
    try:
        env.reset(seed=0, options={"mode": "slow", "arg": 1.0})
        pid = _inner(env).worker.pid
        main = threading.get_ident()
        timer = threading.Timer(0.3, lambda: signal.pthread_kill(main, signal.SIGINT))
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            env.step(env.action_space.sample())
        timer.join()
        assert _wait_gone(pid)
        with pytest.raises(errors.EnvCrashedError, match="interrupted"):
            env.step(env.action_space.sample())
        env.reset(seed=0)  # restart=True: a fresh worker, in step again
        obs, _, _, _, info = env.step(env.action_space.sample())
        assert "probe" not in info and obs["agent_pos"].shape == (2,)
    finally:
        env.close()


def test_ctrl_c_during_a_vector_step_stops_every_worker(published, ctrl_c):
    """Ctrl-C while a vector step is gathered: the answers not read yet would come out of step, so every worker
    of the vector env is stopped and the next step says it was interrupted."""
    import threading

    loaded = load_env(published["hostile"], trust_remote_code=True, isolation="process", check=False, envs_per_worker=1)
    vec = loaded.make_vec(2)
    try:
        assert len(vec._workers) == 2
        vec.reset(seed=0, options={"mode": "slow", "arg": 1.0})
        pids = [w.pid for w in vec._workers]
        main = threading.get_ident()
        timer = threading.Timer(0.3, lambda: signal.pthread_kill(main, signal.SIGINT))
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            vec.step(np.stack([vec.single_action_space.sample() for _ in range(2)]))
        timer.join()
        assert all(_wait_gone(pid) for pid in pids)
        with pytest.raises(errors.EnvCrashedError, match="interrupted"):
            vec.step(np.stack([vec.single_action_space.sample() for _ in range(2)]))
    finally:
        vec.close()
        loaded.unregister()


def test_a_worker_cannot_shrink_the_pages_it_shares_with_the_parent(hostile):
    """The doorbell page and the observation buffers are sealed memfds: env code truncating them (which would make
    the parent's next read of its mapping a SIGBUS) is refused. Run in a child process, so that a regression
    kills that child, not the test run."""
    factory = gym.spec(hostile.gym_id).entry_point
    t = factory.target
    script = textwrap.dedent(
        f"""
        import json
        from pathlib import Path
        from hub_envs.isolation.proxy import EnvTarget, IsolatedEnv, IsolationOptions
        target = EnvTarget({t.repo_id!r}, {t.revision!r}, Path({str(t.path)!r}), {t.key!r}, {t.entry_point!r})
        env = IsolatedEnv(target, IsolationOptions(isolation="process"), {{}})
        env.reset(seed=0, options={{"mode": "shrink"}})
        probe = env.step(env.action_space.sample())[4]["probe"]
        for _ in range(200):  # the parent reads both pages at every step
            obs = env.step(env.action_space.sample())[0]
        print(json.dumps({{"probe": probe, "obs": obs["agent_pos"].tolist()}}))
        env.close()
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert done.returncode == 0, f"the parent died (code {done.returncode}): {done.stderr[-2000:]}"
    out = json.loads(done.stdout.strip().splitlines()[-1])
    names = sorted(out["probe"])
    assert any("doorbell" in n for n in names) and any("obs" in n for n in names), names
    assert all(v.startswith("refused") for v in out["probe"].values()), out["probe"]
    assert len(out["obs"]) == 2


@pytest.mark.parametrize("spin", [True, False], ids=["busy-wait", "sleep"])
def test_busy_waiting_and_sleeping_give_the_same_steps(published, spin):
    """Both ways of waiting for a worker (hub_envs.isolation.doorbell) give the in-process env's steps exactly:
    busy-waiting with the messages in the shared page, and sleeping in the socket; every answer rang once."""
    from hub_envs.isolation import doorbell

    here = load_env(published["pendulum"], trust_remote_code=True)
    isolated = load_env(published["pendulum"], trust_remote_code=True, isolation="process", check=False)
    doorbell.enabled = spin
    a, b = here.make(), isolated.make()
    try:
        assert _same(_rollout(a, 5, 60), _rollout(b, 5, 60))
        worker = _inner(b).worker
        if not spin:
            assert not worker.spins
        heard = worker.bell.heard
        assert worker.bell._slots[doorbell.REPLY] == heard > 60  # every answer rang, and only once
        assert worker.bell._mailed_in is (spin and doorbell.MAIL)  # busy-waiting, the answers came in the page
    finally:
        doorbell.enabled = True
        a.close()
        b.close()
        here.unregister()
        isolated.unregister()


def test_the_parent_switches_its_way_of_waiting_and_every_way_gives_the_same_steps(published):
    """The parent chooses, step by step, how to wait for its worker (busy-wait, sleep on its CPU, sleep wherever the
    scheduler puts it: hub_envs.isolation.doorbell.WaitChooser) by what each way costs on this machine now, and tries
    the others now and then: a rollout that goes through the ways gives the in-process env's steps exactly."""
    here = load_env(published["pendulum"], trust_remote_code=True)
    isolated = load_env(published["pendulum"], trust_remote_code=True, isolation="process", check=False)
    a, b = here.make(), isolated.make()
    try:
        assert _same(_rollout(a, 7, 90), _rollout(b, 7, 90))
        tried = {way for way, usual in _inner(b)._waits.usual.items() if usual is not None}
        # the busy-wait is only possible while steps are short on a machine with CPUs to spare; the two ways of
        # sleeping always are (the first steps sleep, the pinned sleep is tried from the 32nd)
        assert {"pin", "sleep"} <= tried, tried
    finally:
        a.close()
        b.close()
        here.unregister()
        isolated.unregister()


def test_a_worker_has_its_own_process_group_in_its_parents_session_unless_sandboxed(hostile, sandboxed):
    """A worker is the leader of its own process group (killed whole; the terminal's Ctrl-C goes to the parent's
    group only) in the parent's session: a session is an autogroup of the scheduler, and a worker alone in one
    waits far longer for a CPU on a busy machine. A sandboxed worker gets a session of its own: no controlling
    terminal its code could write escape sequences to or push input into."""
    env, boxed = hostile.make(), sandboxed.make()
    try:
        pid, boxed_pid = _inner(env).worker.pid, _inner(boxed).worker.pid
        assert os.getpgid(pid) == pid != os.getpgrp() and os.getsid(pid) == os.getsid(0)
        assert os.getsid(boxed_pid) == boxed_pid != os.getsid(0)
    finally:
        env.close()
        boxed.close()


def test_no_worker_outlives_its_parent(hostile, tmp_path):
    """The parent is SIGKILLed (no cleanup of its own runs): the kernel's parent-death signal ends the worker."""
    from hub_envs.isolation.proxy import EnvTarget

    target = hostile.make.__self__  # noqa: F841 - keep the loaded env alive
    factory = gym.spec(hostile.gym_id).entry_point
    t: EnvTarget = factory.target
    script = textwrap.dedent(
        f"""
        import sys, time
        from pathlib import Path
        from hub_envs.isolation.proxy import EnvTarget, IsolatedEnv, IsolationOptions
        target = EnvTarget({t.repo_id!r}, {t.revision!r}, Path({str(t.path)!r}), {t.key!r}, {t.entry_point!r})
        env = IsolatedEnv(target, IsolationOptions(isolation="process"), {{}})
        print(env.worker.pid, flush=True)
        time.sleep(120)
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    try:
        pid = int(proc.stdout.readline())
        assert _alive(pid)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert _wait_gone(pid), "the worker outlived its SIGKILLed parent"
    finally:
        proc.kill()
        proc.wait()


def test_unimplemented_options_are_refused_not_ignored(published):
    with pytest.raises(errors.ConfigError, match="versions='publisher'.*isolation='venv'"):
        load_env(published["pendulum"], trust_remote_code=True, isolation="process", versions="publisher")
    with pytest.raises(errors.ConfigError, match="isolation='threads'"):
        load_env(published["pendulum"], trust_remote_code=True, isolation="threads")


def test_isolation_does_not_replace_consent(published):
    with pytest.raises(errors.UntrustedCodeError):
        load_env(published["hostile"], isolation="process")


# --- sandbox=True ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sandboxed(published):
    return load_env(
        published["hostile"],
        trust_remote_code=True,
        sandbox=True,
        check=False,
        step_timeout=3,
        restart=True,
        sandbox_limits={"memory_mb": 768, "processes": 32},
    )


def _probe(env, mode: str, arg=None):
    env.reset(seed=0, options={"mode": mode, "arg": arg})
    return env.step(env.action_space.sample())[4].get("probe")


def test_sandboxed_env_code_cannot_read_secrets_reach_the_hub_or_write_files(sandboxed, hub_module, monkeypatch, tmp_path):
    from urllib.parse import urlparse

    home = Path(os.path.expanduser("~"))
    url = urlparse(hub_module.endpoint)
    env = sandboxed.make()
    try:
        seen = _probe(env, "env", ["HF_TOKEN", "HOME", "HF_ENDPOINT", "AWS_SECRET_ACCESS_KEY"])
        assert seen["HF_TOKEN"] is None and seen["AWS_SECRET_ACCESS_KEY"] is None and seen["HF_ENDPOINT"] is None
        assert seen["HOME"].startswith("/tmp/")
        # no network: not even the loopback Hub this process talks to
        assert _probe(env, "connect", [url.hostname, url.port]).startswith("refused")
        # the env's own files (its verified copy) are read-only, and so is the snapshot it came from
        assert "Read-only file system" in _probe(env, "write", "/tmp/env/hostile.py")
        assert _probe(env, "write", str(sandboxed.path / "hostile.py")).startswith("refused")
        # the user's home is not visible (empty) and not writable
        assert not [p for p in _probe(env, "listdir", str(home)) if not p.startswith(".pyenv")]
        assert _probe(env, "write", str(home / "pwned")).startswith("refused")
        assert not (home / "pwned").exists()
        assert _probe(env, "write", "/work/pwned").startswith("refused")
        # its private temp dir is writable
        assert _probe(env, "write", "/tmp/scratch.txt") == "written"
    finally:
        env.close()


def test_sandbox_keeps_secrets_out_even_when_set(sandboxed, monkeypatch):
    monkeypatch.setenv("HF_TOKEN", "hf_secret_for_the_sandbox_test")
    monkeypatch.setenv("MY_SERVICE_API_KEY", "k")
    env = sandboxed.make()
    try:
        seen = _probe(env, "env", ["HF_TOKEN", "MY_SERVICE_API_KEY"])
        assert seen == {"HF_TOKEN": None, "MY_SERVICE_API_KEY": None}
    finally:
        env.close()


@pytest.mark.parametrize(
    ("mode", "arg", "error"),
    [
        ("hang", None, errors.EnvTimeoutError),
        ("memory", 1024, errors.EnvCrashedError),  # 1 GB: more than the sandbox's 768 MB, not more than this machine has
        ("forkbomb", None, errors.HubEnvsError),
    ],
)
def test_hostile_loads_are_stopped_with_a_typed_error_and_the_parent_keeps_running(sandboxed, mode, arg, error):
    env = sandboxed.make()
    try:
        env.reset(seed=0, options={"mode": mode, "arg": arg})
        pid = _inner(env).worker.pid
        with pytest.raises(error) as info:
            env.step(env.action_space.sample())
        assert sandboxed.repo_id in str(info.value)
        print(f"{mode}: {type(info.value).__name__}: {info.value}")
        if mode != "forkbomb":
            assert _wait_gone(pid)
        obs, _ = env.reset(seed=1)  # restart=True after a crash or timeout: a fresh sandboxed worker
        assert env.observation_space.contains(obs)
    finally:
        env.close()
    assert _wait_gone(pid) and _group_gone(pid), "a process the env started outlived its sandbox"


def _group_gone(pgid: int, seconds: float = 10.0) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        members = []
        for d in os.listdir("/proc"):
            if d.isdigit():
                try:
                    with open(f"/proc/{d}/stat") as f:
                        fields = f.read().rsplit(")", 1)[1].split()
                except OSError:
                    continue
                if int(fields[2]) == pgid and fields[0] != "Z":
                    members.append(d)
        if not members:
            return True
        time.sleep(0.1)
    return False


def test_a_sandboxed_env_steps_bit_identically_also_vectorized(published):
    ref = published["pendulum"]
    here = load_env(ref, trust_remote_code=True)
    boxed = load_env(ref, trust_remote_code=True, sandbox=True, check=False, envs_per_worker=2)
    a, b = here.make(max_episode_steps=10), boxed.make(max_episode_steps=10)
    try:
        assert _same(_rollout(a, 5, 14), _rollout(b, 5, 14))
    finally:
        a.close()
        b.close()
    va, vb = here.make_vec(3, max_episode_steps=6), boxed.make_vec(3, max_episode_steps=6)
    try:
        assert _same(vb.reset(seed=2), va.reset(seed=2))
        vb.action_space.seed(0)
        for _ in range(8):
            actions = vb.action_space.sample()
            assert _same(vb.step(actions), va.step(actions))
    finally:
        va.close()
        vb.close()
    here.unregister()
    boxed.unregister()


def test_cli_load_and_reproduce_take_the_isolation_flags(published, tmp_path, capsys):
    from hub_envs.cli import main

    repo, sha = published["pendulum"].split("@")
    assert main(["load", f"--repo_id={repo}@{sha}", "--trust_remote_code=true", "--isolation=process"]) == 0
    assert "runs:        in a worker process" in capsys.readouterr().out
    assert main(["load", f"--repo_id={repo}@{sha}", "--trust_remote_code=true", "--versions=publisher"]) == 1
    assert "ConfigError" in capsys.readouterr().err
    code = main(
        ["reproduce", f"--repo_id={repo}", f"--revision={sha}", "--trust_remote_code=true", "--sandbox=true", "--workers=1"]
        + [f"--out={tmp_path / 'out'}", "--resamples=50"]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.startswith(f"REPRODUCED: {repo}@{sha}")
    report = (tmp_path / "out" / "report.json").read_text()
    assert '"isolation": "none+sandbox"' in report or '"isolation": "process+sandbox"' in report


# --- isolation="venv" -----------------------------------------------------------------------------


def test_a_venv_worker_runs_in_the_venv_built_from_the_envs_requirements(published):
    from hub_envs.isolation.venvs import venvs_root

    loaded = load_env(published["hostile"], trust_remote_code=True, isolation="venv", check=False)
    env = loaded.make()
    try:
        seen = _probe(env, "versions")
        venv = Path(seen["prefix"])
        assert venv.parent == venvs_root() and (venv / "hub-envs-venv.json").is_file()
        record = json.loads((venv / "hub-envs-venv.json").read_text())
        assert f"numpy=={seen['numpy']}" in record["installed"] and "torch" not in " ".join(record["installed"])
        assert not any(p.startswith("lerobot") for p in record["installed"])  # the worker venv stays small
    finally:
        env.close()
    # a second load reuses it: no second build, no uv, no network needed
    again = load_env(published["hostile"], trust_remote_code=True, isolation="venv", sandbox=True, check=False)
    env = again.make()
    try:
        assert _probe(env, "versions")["prefix"] == str(venv)  # sandboxed, in the same venv
    finally:
        env.close()
    builds = (venvs_root() / "builds.log").read_text().split()
    assert builds.count(venv.name) == 1


def test_a_check_verdict_is_reused_only_with_the_packages_the_checks_ran_with(published, hub_module):
    """The checks of one commit, in this process and in venv workers (the packages here, the publisher's): a
    verdict is reused only where it was reached. A venv worker's numpy is not this process's (issue 29 saw a
    worker on numpy 2.4.6 answer "cached" from a run on 2.2.6)."""
    ref = published["hostile"]
    fingerprint = {}
    records = {}
    for name, kw in (
        ("here", {}),
        ("here again", {}),
        ("venv", {"isolation": "venv"}),
        ("venv again", {"isolation": "venv"}),
        ("publisher venv", {"isolation": "venv", "versions": "publisher"}),
    ):
        loaded = load_env(ref, trust_remote_code=True, **kw)
        fingerprint[name] = loaded.report.fingerprint
        records[name] = loaded.worker_venv
        loaded.unregister()
    assert "cached" not in fingerprint["here"] and "cached" in fingerprint["here again"]
    assert "cached" not in fingerprint["venv"], "a verdict reached in this process was reused in a venv worker"
    assert "cached" in fingerprint["venv again"] and "in the same worker venv" in fingerprint["venv again"]
    # the publisher's venv (this stack's versions, as recorded) and the venv of the newest compatible versions:
    # a verdict crosses between them only if they hold the very same packages
    same = sorted(records["publisher venv"]["installed"]) == sorted(records["venv"]["installed"])
    assert ("cached" in fingerprint["publisher venv"]) is same, (
        records["publisher venv"]["installed"],
        records["venv"]["installed"],
    )


def test_sixteen_concurrent_loaders_build_one_venv(hub_module, tmp_path):
    from hub_envs.isolation.venvs import venv_digest, venvs_root

    reqs = ["gymnasium>=1.0.0", "numpy>=1.20"]  # a digest no other test builds
    code = f"from hub_envs.isolation.venvs import venv_for; print(venv_for({reqs!r}, where='concurrent')[0])"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env) for _ in range(16)]
    outs = [p.communicate(timeout=300)[0].strip() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    digest = venv_digest(reqs, f"{sys.version_info[0]}.{sys.version_info[1]}")
    assert set(outs) == {str(venvs_root() / digest)}
    assert (venvs_root() / "builds.log").read_text().split().count(digest) == 1
    assert not [p for p in venvs_root().iterdir() if p.name.startswith(f".{digest}")]  # no half-built venv


def test_a_requirement_uv_cannot_resolve_is_a_typed_error_and_leaves_nothing(hub_module):
    from hub_envs.isolation.venvs import venv_digest, venv_for, venvs_root

    with pytest.raises(errors.VenvBuildError, match="numpy>=99") as info:
        venv_for(["numpy>=99"], where="iso/broken@0123")
    assert "iso/broken@0123" in str(info.value) and "unsatisfiable" in str(info.value)
    digest = venv_digest(["numpy>=99"], f"{sys.version_info[0]}.{sys.version_info[1]}")
    assert not (venvs_root() / digest).exists()
    assert not [p for p in venvs_root().iterdir() if p.name.startswith(f".{digest}")]


def test_versions_publisher_pins_the_recorded_versions_and_python(published, hub_module):
    """The hostile env republished as if from the compat stack (python 3.11, numpy 2.3.5): the worker runs
    exactly those; pushed from here, the same env's worker runs this stack's versions (not the newest)."""
    from helpers import republish

    here_numpy = np.__version__
    loaded = load_env(published["hostile"], trust_remote_code=True, isolation="venv", versions="publisher", check=False)
    env = loaded.make()
    try:
        seen = _probe(env, "versions")
        assert seen["numpy"] == here_numpy and seen["gymnasium"] == gym.__version__
    finally:
        env.close()

    from importlib.metadata import version

    assert loaded.manifest.resolved["cloudpickle"] == version("cloudpickle")  # gymnasium's dependency, recorded
    assert {"gymnasium", "numpy", "farama-notifications"} <= set(loaded.manifest.resolved)

    def as_compat(folder: Path) -> None:
        manifest = json.loads((folder / "hub_env.json").read_text())
        manifest["versions"].update({"python": "3.11.7", "numpy": "2.3.5"})
        manifest["resolved"].update({"numpy": "2.3.5", "cloudpickle": "3.0.0"})  # a dependency of a dependency
        (folder / "hub_env.json").write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")

    sha = republish(hub_module.api, "iso/hostile", as_compat)
    compat = load_env(f"iso/hostile@{sha}", trust_remote_code=True, isolation="venv", versions="publisher", check=False)
    env = compat.make()
    try:
        seen = _probe(env, "versions")
        assert seen["numpy"] == "2.3.5" and "/venvs/" in seen["prefix"]
    finally:
        env.close()
    record = compat.worker_venv
    assert record["python"] == seen["python"]
    assert "cloudpickle==3.0.0" in record["installed"]  # the closure is held, not only the requirements
    if any("is not installed here" in n for n in record["notes"]):  # no python 3.11 on this machine: said so
        assert seen["python"] == platform.python_version()
    else:
        assert seen["python"].startswith("3.11.")


def test_reproduce_in_a_publisher_venv_reports_the_workers_versions(published, tmp_path):
    from hub_envs import reproduce

    repo, sha = published["pendulum"].split("@")
    report = reproduce(
        repo,
        revision=sha,
        trust_remote_code=True,
        isolation="venv",
        versions="publisher",
        workers=1,
        benchmarks=False,
        progress=False,
        out=tmp_path,
        resamples=10,
    )
    assert report.reproduced, report.summary()
    worker = report.provenance["worker"]
    assert "/venvs/" in worker["venv"] and worker["versions"]["numpy"] == np.__version__
    assert "numpy" not in report.provenance["version_differences"]


def _affinity_becomes(pid: int, want, seconds: float = 10.0) -> set[int]:
    deadline = time.monotonic() + seconds
    while (cpus := os.sched_getaffinity(pid)) != want and not (callable(want) and want(cpus)):
        if time.monotonic() > deadline:
            break
        time.sleep(0.01)
    return cpus


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: there is nothing to place")
def test_a_worker_sleeps_on_its_callers_cpu_but_runs_the_env_on_all_of_its_own(hostile):
    """The wake-up placement (hub_envs.isolation.affinity), when the parent sleeps on its CPU (the way of waiting
    it picks where waking an idle CPU is costly; here the only one it may pick): between steps the worker waits
    pinned to the CPU the stepping thread waited on; the env's step itself runs with the worker's whole CPU set;
    the calling thread gets its own CPU set back after every step; with affinity off nothing is pinned."""
    from hub_envs.isolation import affinity, doorbell

    env = hostile.make()
    _inner(env)._waits = doorbell.WaitChooser((doorbell.PIN,))
    mine = os.sched_getaffinity(0)
    try:
        pid = _inner(env).worker.pid
        seen = _probe(env, "cpus")
        assert os.sched_getaffinity(0) == mine
        assert seen == sorted(mine)  # the env's code is not confined to one CPU
        sleeping = _affinity_becomes(pid, lambda cpus: len(cpus) == 1)
        assert len(sleeping) == 1 and sleeping <= mine
        assert _probe(env, "cpus") == sorted(mine)
        affinity.enabled = False
        env.step(env.action_space.sample())
        assert os.sched_getaffinity(0) == mine
        assert _affinity_becomes(pid, mine) == mine
    finally:
        affinity.enabled = True
        env.close()


def test_an_env_made_in_a_thread_that_ended_keeps_its_worker(hostile):
    """The parent-death signal follows the thread that started the worker: workers start from one long-lived
    launcher thread, so an env made in a short-lived thread (a pool, a loader) keeps working after it ends."""
    import threading

    made = []
    thread = threading.Thread(target=lambda: made.append(hostile.make()))
    thread.start()
    thread.join()
    env = made[0]
    try:
        time.sleep(0.3)
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()


def test_lerobot_hub_env_config_takes_the_isolation_fields(published):
    """``--env.type=hub --env.isolation=process``: LeRobot's eval loop gets vector envs whose envs run in workers,
    stepping exactly as the in-process ones."""
    from hub_envs.lerobot.env import HubEnv

    repo, sha = published["pendulum"].split("@")
    here = HubEnv(repo_id=repo, revision=sha, trust_remote_code=True)
    isolated = HubEnv(repo_id=repo, revision=sha, trust_remote_code=True, isolation="process", check=False)
    assert isolated.features == here.features and isolated.episode_length == here.episode_length
    (va,) = here.create_envs(2)[here.loaded.manifest.name].values()
    (vb,) = isolated.create_envs(2)[isolated.loaded.manifest.name].values()
    try:
        assert isinstance(vb.envs[0].unwrapped, IsolatedEnv)
        assert _same(vb.reset(seed=3), va.reset(seed=3))
        vb.action_space.seed(1)
        for _ in range(5):
            actions = vb.action_space.sample()
            assert _same(vb.step(actions), va.step(actions))
    finally:
        va.close()
        vb.close()


def test_config_overrides_on_an_isolated_load_run_the_config_class_in_a_worker(published):
    """``--env.overrides`` / ``--env.episode_length`` with isolation: the repo's config class computes them in
    a worker (the parent imports none of the repo's code), and the envs follow them as in-process ones do."""

    from hub_envs.lerobot.env import HubEnv

    repo, sha = published["pendulum"].split("@")
    fields = {"overrides": {"g": "3.0", "obs_type": "pixels_agent_pos"}, "episode_length": 7}
    here = HubEnv(repo_id=repo, revision=sha, trust_remote_code=True, **fields)
    isolated = HubEnv(repo_id=repo, revision=sha, trust_remote_code=True, isolation="process", check=False, **fields)
    assert isolated.loaded.config_class is None  # the parent has the values only, computed in a worker
    assert isolated.env_config.g == 3.0 and isolated.episode_length == 7
    assert isolated.features == here.features and "pixels" in isolated.features  # __post_init__ ran on the override
    assert isolated.gym_kwargs == here.gym_kwargs
    (va,) = here.create_envs(1)[here.loaded.manifest.name].values()
    (vb,) = isolated.create_envs(1)[isolated.loaded.manifest.name].values()
    try:
        assert _same(vb.reset(seed=5), va.reset(seed=5))
        for t in range(7):
            out_a, out_b = va.step(np.array([[1.0]])), vb.step(np.array([[1.0]]))
            assert _same(out_b[:4], out_a[:4]), t  # gravity 3.0 in both
        assert bool(out_b[3][0]) and bool(out_a[3][0])  # truncated at the overridden episode length
        assert _same(out_b[4]["final_obs"][0], out_a[4]["final_obs"][0])
    finally:
        va.close()
        vb.close()
    with pytest.raises(errors.ConfigError, match=r"no field\(s\) \['gravity'\]"):
        HubEnv(repo_id=repo, revision=sha, trust_remote_code=True, isolation="process", overrides={"gravity": 3.0})
