"""Scale-out on Ray (``--backend=ray``): the same results as the local backend, on a real Ray cluster.

Run by ``tests/test_ray.py`` in a pytest process of its own (``python -m pytest tests/ray_cases.py`` runs it
directly), so what Ray leaves in a process stays out of the rest of the suite (see :func:`_release_gcs_clients`).

One cluster for the module (``ray.cluster_utils.Cluster`` on 127.0.0.1: a head and one more node, one CPU
each, dashboard off, a small object store), started after the module's loopback Hub, and always shut down.
The nodes' own ``HF_ENDPOINT`` is :func:`worker_path`, a proxy in front of that Hub (honest unless a test makes
it lie): the workers' path to the Hub, which need not be the driver's. Episode counts stay tiny: Ray is slow to
start on a busy machine.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import ray
from helpers import TINY, comparable_report, copy_env, republish
from lying_endpoint import LyingEndpoint
from ray.cluster_utils import Cluster

from hub_envs import errors, evaluate, load_env, push_env, reproduce
from hub_envs.backends import LocalBackend, make_backend
from hub_envs.backends.ray import RayBackend
from hub_envs.testing import hub_environment

ENVS = Path(__file__).resolve().parent.parent / "envs"
NODE = {"num_cpus": 1, "object_store_memory": 80 * 2**20}


def _start_cluster(attempts: int = 3) -> Cluster:
    """A head and one more node. Ray gives a raylet 30 s (hard-coded) to register: on a saturated machine
    that can run out, so a failed start is cleaned up and tried again."""
    for attempt in range(attempts):
        c = Cluster(initialize_head=False)
        try:
            # the first node is the head; its system config holds for every node: workers at the niceness of
            # the rest of the suite (Ray's default, nice 15, starves them on a busy machine)
            c.add_node(**NODE, include_dashboard=False, _system_config={"worker_niceness": 0})
            c.add_node(**NODE)
            c.wait_for_nodes()
            return c
        except Exception:
            _shutdown(c)
            if attempt == attempts - 1:
                raise
    raise AssertionError("unreachable")


@pytest.fixture(scope="module")
def worker_path(hub_module):
    """The nodes' own path to the Hub (their ``HF_ENDPOINT``): a proxy in front of the module's Hub, honest until a
    test sets its ``rewrite_path`` / ``rewrite_answer`` (and sets them back)."""
    with LyingEndpoint(hub_module.endpoint) as proxy:
        yield proxy


@pytest.fixture(scope="module")
def cluster(hub_module, worker_path):
    # Ray replaces 127.0.0.1 by this machine's outward address (services.resolve_ip_for_localhost) unless
    # it is told this host is not part of a multi-machine cluster: then every node and worker stays on loopback.
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # for the cluster's processes
        mp.setattr(ray._private.ray_constants, "ENABLE_RAY_CLUSTER", False)  # for this driver (read at import)
        mp.setenv("RAY_DEDUP_LOGS", "0")
        with pytest.MonkeyPatch.context() as node:  # the nodes' environment only: this driver keeps its endpoint
            node.setenv("HF_ENDPOINT", worker_path.endpoint)
            c = _start_cluster()
        try:
            assert c.address.startswith("127.0.0.1:")
            # one driver connection for the module: every run below reuses it (a run connects by itself otherwise)
            ray.init(address=c.address, log_to_driver=False, logging_level="warning")
            yield c
        finally:
            ray.shutdown()
            _shutdown(c)


def _shutdown(c: Cluster) -> None:
    nodes = [c.head_node, *c.worker_nodes]  # shutdown() forgets them
    c.shutdown()
    _release_gcs_clients(nodes)


def _release_gcs_clients(nodes: list) -> None:
    """Destroy the GCS clients the cluster's node objects hold, here and now.

    A non-head ``ray._private.node.Node`` keeps a GCS client (it fetched the system config with it), and Ray's
    ``atexit`` hook for the node (a closure over it) keeps the node alive after the cluster is shut down. A
    process forked later (the rollout engine's pool) runs ``atexit._clear()`` first thing (multiprocessing's
    ``_bootstrap``), which drops that last reference *in the child*: the client's destructor shuts a gRPC
    completion queue whose threads do not exist there, and the child dies of SIGSEGV before running anything
    (``BrokenProcessPool`` in the parent; core dump: ``~GcsClient`` -> ``grpc_completion_queue_shutdown`` ->
    ``pollset_shutdown``). Destroyed in this process, where gRPC is still whole, nothing is left to crash.
    """
    for node in nodes:
        if node is not None and getattr(node, "_gcs_client", None) is not None:
            node._gcs_client = None


def _gain(folder: Path) -> None:
    path = folder / "dynamics.py"
    path.write_text(path.read_text().replace("GAIN = 1.0\n", "GAIN = 1.05\n"))


def _busy_workers() -> list[int]:
    """pids of this machine's Ray worker processes running a shard of episodes right now."""
    out = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            if cmd.startswith(b"ray::run_shard"):
                out.append(int(pid))
    return out


def toward_origin(obs, t):
    """A tiny deterministic policy: push the point mass toward the origin."""
    return np.clip(-2.0 * obs["agent_pos"][:1], -1.0, 1.0).astype(np.float32)


# Ray pickles a function by reference when its module is importable here; the workers cannot import this
# test module, so its functions travel by value (what a user does for a policy defined in a script).
ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])


# --- push_env ------------------------------------------------------------------------------------


def test_push_on_ray_publishes_exactly_what_the_local_backend_publishes(cluster, hub_module):
    kw = {"episodes": 4, "config": {"episode_length": 12}, "determinism_steps": 6, "progress": False}
    local = push_env(ENVS / "hover", "ray/hover", backend="local", workers=1, **kw)
    on_ray = push_env(ENVS / "hover", "ray/hover", backend="ray", ray_address=cluster.address, force=True, **kw)
    # same content: no new commit, the same content tag, every file (dataset, states, card) hashed the same
    assert on_ray.created_commit is False and on_ray.sha == local.sha
    assert on_ray.content_tag == local.content_tag
    assert on_ray.manifest.files == local.manifest.files
    assert on_ray.manifest.dataset["episodes"] == 4 and on_ray.manifest.dataset["env_states"]


def test_a_suite_pushes_and_reproduces_task_by_task_on_ray(cluster, hub_module):
    """Each task's episodes run in that task's env on the workers (the task travels with the env's source): the
    same commit as the local backend's, and every task reproduced on Ray."""
    suite = Path(__file__).resolve().parent / "fixtures" / "suite_env"
    local = push_env(suite, "ray/suite", episodes=2, workers=1, progress=False)
    on_ray = push_env(suite, "ray/suite", episodes=2, backend="ray", ray_address=cluster.address, force=True, progress=False)
    assert on_ray.created_commit is False and on_ray.sha == local.sha and on_ray.manifest.files == local.manifest.files
    report = reproduce(
        "ray/suite",
        revision=local.sha,
        trust_remote_code=True,
        backend="ray",
        ray_address=cluster.address,
        write=False,
        progress=False,
    )
    assert report.reproduced and [(t.task, t.reproduced) for t in report.tasks] == [
        ("reach-left", True),
        ("reach-center", True),
        ("reach-right", True),
    ]


# --- reproduce -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny(hub_module):
    """alice/tiny: published (3 episodes), and a perturbed commit of it (a changed physics constant)."""
    first = push_env(TINY, "ray/tiny", episodes=3, progress=False, workers=1)
    perturbed = republish(hub_module.api, "ray/tiny", _gain, message="stronger motor")
    return first.sha, perturbed


def test_reproduce_on_ray_passes_and_finds_the_same_divergence(cluster, tiny, tmp_path):
    good, bad = tiny
    on_ray = reproduce(
        "ray/tiny", revision=good, trust_remote_code=True, backend="ray", ray_address=cluster.address, write=False, progress=False
    )
    assert on_ray.reproduced and on_ray.settings["backend"] == "ray"
    local = reproduce("ray/tiny", revision=bad, trust_remote_code=True, workers=2, write=False, progress=False)
    remote = reproduce(
        "ray/tiny", revision=bad, trust_remote_code=True, backend="ray", ray_address=cluster.address, write=False, progress=False
    )
    assert not remote.reproduced
    first = remote.replay.first_divergence
    assert (first.episode, first.step, first.feature) == (
        local.replay.first_divergence.episode,
        local.replay.first_divergence.step,
        local.replay.first_divergence.feature,
    )
    assert comparable_report(remote) == comparable_report(local)  # the whole report, timings aside


def _isolated_workers_under_ray() -> list[int]:
    """pids of isolated env worker processes (hub_envs.isolation.worker) whose parent is a Ray worker process."""
    out = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
            ppid = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1]
            parent = Path(f"/proc/{ppid}/cmdline").read_bytes()
        except (OSError, IndexError):
            continue
        if b"hub_envs.isolation.worker" in cmd and parent.startswith(b"ray::"):
            out.append(int(pid))
    return out


def test_isolated_eval_on_ray_equals_the_local_in_process_eval(cluster, tiny):
    """``--isolation=process`` on Ray: each Ray worker loads the env isolated (its code runs in a worker process of
    the Ray worker), and the per-episode returns are those of the local in-process run."""
    good, _ = tiny
    ref = f"ray/tiny@{good}"
    kw = {"policy": toward_origin, "episodes": 4, "seed": 20, "trust_remote_code": True, "progress": False}
    local = evaluate(ref, workers=1, **kw)
    before = set(_isolated_workers_under_ray())
    isolated = evaluate(ref, isolation="process", backend="ray", ray_address=cluster.address, workers=1, **kw)
    assert isolated.isolation == "process" and isolated.backend["backend"] == "ray" and local.isolation == "none"
    assert isolated.returns == local.returns and isolated.lengths == local.lengths and isolated.metrics == local.metrics
    # the Ray workers keep the run's env: its code runs in processes of theirs, not in the Ray workers themselves
    assert set(_isolated_workers_under_ray()) - before


# --- evaluation, worker deaths, resumed runs ------------------------------------------------------


def test_eval_metrics_are_the_same_on_both_backends(cluster, tiny):
    good, _ = tiny
    ref = f"ray/tiny@{good}"
    local = evaluate(ref, policy=toward_origin, episodes=5, seed=10, trust_remote_code=True, workers=2, progress=False)
    remote = evaluate(
        ref, policy=toward_origin, episodes=5, seed=10, trust_remote_code=True, backend="ray", ray_address=cluster.address,
        progress=False,
    )  # fmt: skip
    assert remote.metrics == local.metrics and remote.returns == local.returns and remote.successes == local.successes
    random = evaluate(ref, episodes=5, seed=10, trust_remote_code=True, workers=1, progress=False)
    assert random.returns != local.returns  # the policy mattered: the comparison above is not vacuous
    assert remote.backend["backend"] == "ray" and remote.sha == good


def test_compare_on_ray_gives_the_local_comparison(cluster, tiny, tmp_path):
    """``hub-envs compare --backend=ray``: the same per-seed returns and paired differences as on local processes."""
    from hub_envs import compare

    good, _ = tiny
    ref = f"ray/tiny@{good}"
    options = dict(episodes=4, seed=3, trust_remote_code=True, progress=False, write=False)
    local = compare(ref, ["random", "random"], workers=2, **options)
    remote = compare(ref, ["random", "random"], backend="ray", ray_address=cluster.address, **options)
    assert [p.returns for p in remote.policies] == [p.returns for p in local.policies]
    assert remote.differences[0].returns.values == local.differences[0].returns.values == (0.0,) * 4
    assert remote.settings["backend"]["backend"] == "ray" and local.settings["backend"]["backend"] == "local"


def _loaded(sha: str):
    loaded = load_env(f"ray/tiny@{sha}", trust_remote_code=True, check=False, fingerprint="off")
    return loaded


def slow_toward_origin(obs, t):
    """The same policy, slowed down: a shard is still running when the test kills its worker."""
    time.sleep(0.05)
    return toward_origin(obs, t)


def test_a_killed_worker_is_retried_and_the_result_is_identical(cluster, tiny):
    good, _ = tiny
    loaded = _loaded(good)
    try:
        seeds = list(range(6))
        kw = {"max_steps": 20, "policy": slow_toward_origin, "progress": False}
        expected = list(LocalBackend(workers=1).episodes(loaded, seeds, **kw))
        run = RayBackend(address=cluster.address, workers=2, shard_size=1).episodes(loaded, seeds, **kw)
        got = [next(run)]
        deadline = time.monotonic() + 60
        while not (busy := _busy_workers()) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert busy, "no Ray worker was running a shard"
        os.kill(busy[0], signal.SIGKILL)  # mid-shard
        got += list(run)
        assert got == expected  # nothing lost, nothing duplicated, in episode order
        assert run.stats["shards_run"] == 6
    finally:
        loaded.unregister()


def test_a_resumed_run_skips_the_checkpointed_shards(cluster, tiny, tmp_path):
    good, _ = tiny
    loaded = _loaded(good)
    try:
        seeds = list(range(8))
        expected = list(LocalBackend(workers=1).episodes(loaded, seeds, max_steps=30, progress=False))
        backend = RayBackend(address=cluster.address, workers=2, shard_size=2, checkpoint_dir=tmp_path / "ckpt")
        first = backend.episodes(loaded, seeds, max_steps=30, progress=False)
        partial = [next(first) for _ in range(5)]  # shards 0, 1 and the first episode of shard 2 ...
        first.close()  # ... then the run is interrupted
        saved = sorted(p.name for p in (tmp_path / "ckpt").rglob("shard-*.pkl"))
        assert saved == ["shard-000000.pkl", "shard-000001.pkl", "shard-000002.pkl"]
        again = backend.episodes(loaded, seeds, max_steps=30, progress=False)
        resumed = list(again)
        assert again.stats == {"episodes": 8, "shards": 4, "shards_run": 1, "shards_resumed": 3}
        assert resumed == expected and partial == expected[:5]
        # another run (other steps) does not pick up these shards
        other = backend.episodes(loaded, seeds[:2], max_steps=31, progress=False)
        assert len(list(other)) == 2 and other.stats["shards_resumed"] == 0
    finally:
        loaded.unregister()


# --- consent on the workers ----------------------------------------------------------------------


def _serve_instead(repo: str, a: str, b: str, after: int = 0):
    """``(rewrite_path, rewrite_answer)`` of a path to the Hub that serves commit ``b`` of ``repo`` whenever ``a`` is
    asked for, and says it is ``a`` (a consistent repo: what a hostile mirror serves), once ``after`` downloads of
    ``repo@a`` were served honestly (a download starts with one listing of the commit: ``/revision/`` on
    huggingface_hub 0.x, ``/tree/`` on 1.x)."""
    seen = {"listings": 0}
    lying = {"on": after == 0}

    def path(method: str, p: str) -> str:
        if p.startswith((f"/api/models/{repo}/revision/{a}", f"/api/models/{repo}/tree/{a}")):
            seen["listings"] += 1
            lying["on"] = lying["on"] or seen["listings"] > after
        return p.replace(a, b) if lying["on"] and repo in p else p

    def answer(method, p, status, headers, body):
        if lying["on"] and repo in p:
            headers = {k: (v.replace(b, a) if k.lower() == "x-repo-commit" else v) for k, v in headers.items()}
            if p.startswith("/api/"):
                body = body.replace(b.encode(), a.encode())
        return status, headers, body

    return path, answer


def _honest(proxy) -> None:
    proxy.rewrite_path = lambda method, path: path
    proxy.rewrite_answer = lambda method, path, status, headers, body: (status, headers, body)


def test_a_worker_whose_hub_serves_other_content_under_the_consented_commit_runs_nothing(cluster, worker_path, tmp_path):
    """The driver consented to ``ray/swapped@A`` (its content); a worker's path to the Hub then serves commit B's files
    (other code, a consistent manifest) under A's id. The worker refuses them with the typed error, naming its node,
    and B's code never runs there (it would write the marker when imported)."""
    marker = tmp_path / "pwned"
    a = push_env(TINY, "ray/swapped", episodes=1, progress=False).sha
    payload = f"import pathlib\npathlib.Path({str(marker)!r}).write_text('pwned')\n"
    b = push_env(
        copy_env(tmp_path, name="swapped", edits={"tiny.py": lambda s: payload + s}), "ray/swapped", episodes=1, progress=False
    ).sha
    marker.unlink()  # push_env imported B's code here, on the publisher's side
    # the driver reaches the Hub through the same proxy (on Ray the workers get the driver's endpoint); A is honest here
    with hub_environment(worker_path.endpoint, tmp_path / "driver"):
        loaded = load_env(f"ray/swapped@{a}", trust_remote_code=True, check=False, fingerprint="off")
        try:
            worker_path.rewrite_path, worker_path.rewrite_answer = _serve_instead("ray/swapped", a, b)
            with pytest.raises(
                errors.UntrustedCodeError, match=r"(?s)on Ray node .*ray/swapped@.* holds content .*not the content"
            ):
                list(RayBackend(address=cluster.address, workers=1).episodes(loaded, [0], max_steps=5, progress=False))
        finally:
            _honest(worker_path)
            loaded.unregister()
    assert worker_path.requests, "the workers did not reach the Hub through their path"
    assert not marker.exists()  # B's code never ran on the worker


def test_a_worker_whose_hub_serves_other_policy_files_refuses_them(cluster, hub_module, worker_path, tmp_path, tiny):
    """The same for a policy checkpoint the workers build their own copy of: the driver consented to ``ray/policy@A``'s
    files; a worker served other files under A refuses them before LeRobot loads anything of them."""
    from test_reproduce import _tiny_lerobot_policy

    api = hub_module.api
    repo = api.create_repo("ray/policy").repo_id
    a = api.upload_folder(repo_id=repo, folder_path=str(_tiny_lerobot_policy(tmp_path / "policy"))).oid
    b = api.upload_file(path_or_fileobj=b"one more file\n", path_in_repo="notes.txt", repo_id=repo).oid  # (a card is not content)
    good, _ = tiny
    with hub_environment(worker_path.endpoint, tmp_path / "driver"):
        # the driver downloads A honestly, every later download of A gets B's files
        worker_path.rewrite_path, worker_path.rewrite_answer = _serve_instead(repo, a, b, after=1)
        try:
            with pytest.raises(errors.UntrustedCodeError, match=r"(?s)on Ray node .*policy ray/policy@.* holds files of content"):
                evaluate(
                    f"ray/tiny@{good}", policy=f"{repo}@{a}", episodes=2, trust_remote_code=True, trust_policy_code=True,
                    backend="ray", ray_address=cluster.address, workers=1, progress=False,
                )  # fmt: skip
        finally:
            _honest(worker_path)


# --- errors --------------------------------------------------------------------------------------


def test_an_unreachable_address_is_a_typed_error_naming_it(tiny):
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"127.0.0.1:{port}"
    with pytest.raises(errors.ClusterUnreachableError, match=address):
        reproduce(f"ray/tiny@{tiny[0]}", trust_remote_code=True, backend="ray", ray_address=address, write=False, progress=False)
    with pytest.raises(errors.ConfigError, match="host:port"):
        make_backend("ray", ray_address="nowhere").__enter__()
    with pytest.raises(errors.ConfigError, match="--backend=ray"):
        make_backend("local", ray_address=address)


def test_a_worker_that_cannot_load_the_env_names_the_node(cluster, hub_module, tmp_path):
    """A requirement missing on the workers' node: the typed error of load_env, naming the node."""
    folder = tmp_path / "needs"
    import shutil

    shutil.copytree(TINY, folder)
    loaded = load_env(folder, check=False)
    try:
        # what the workers get differs from what the driver loaded: a requirement nothing provides
        pyproject = folder / "pyproject.toml"
        pyproject.write_text(pyproject.read_text().replace("dependencies = [", 'dependencies = ["no-such-package-hub-envs>=1", '))
        with pytest.raises(errors.MissingRequirementsError, match=r"(?s)on Ray node 127\.0\.0\.1.*no-such-package-hub-envs"):
            list(RayBackend(address=cluster.address, workers=1).episodes(loaded, [0], max_steps=5, progress=False))
    finally:
        loaded.unregister()


# --- a Ray token on the driver's machine (before Ctrl-C: its driver is another Ray job too) ---------------------------


def test_a_ray_token_on_the_drivers_machine_does_not_break_a_cluster_without_token_auth(cluster, hub_module, tmp_path):
    """A lab user has a Ray token on their machine (``ray.init()`` of a local Ray writes ``~/.ray/auth_token``) and
    ``RAY_AUTH_MODE`` unset, and pushes with ``--backend=ray`` to a cluster started without token authentication (this
    module's). The push's own driver owns what its workers share (``ray.put``): a worker on the other node gets it by
    asking the driver, which refused to answer without the token (hub-envs' look for a token, before connecting, left
    it in Ray's cache), so the push died with ``OwnerDiedError`` ("the object's owner has exited") while its driver was
    running. It publishes what the local backend publishes."""
    import secrets
    import subprocess

    repo = "ray/hover-token"
    kw = {"episodes": 6, "config": {"episode_length": 12}, "determinism_steps": 6, "progress": False}
    local = push_env(ENVS / "hover", repo, workers=1, **kw)
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN_PATH", "RAY_ADDRESS")}
    env["RAY_AUTH_TOKEN"] = secrets.token_hex(32)  # a token found here: another cluster's, or left by a local Ray
    result = subprocess.run(
        [sys.executable, "-m", "hub_envs.cli", "push", f"--env_dir={ENVS / 'hover'}", f"--repo_id={repo}", "--episodes=6",
         "--config.episode_length=12", "--determinism_steps=6", "--force=true", "--backend=ray",
         f"--ray_address={cluster.address}", "--workers=2"],  # two shards at once: one on each node
        env=env, capture_output=True, text=True, timeout=600,  # a hang guard
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    assert "backend=ray" in result.stderr and "Generating 6 episodes" in result.stderr, result.stderr[-3000:]
    assert "OwnerDiedError" not in result.stderr
    # the same content as the local push's: no new commit
    assert f"Unchanged; already published {repo} at commit {local.sha}" in result.stdout, result.stdout[-3000:]
    assert _head(hub_module.api, repo) == local.sha


# --- Ctrl-C (last: its driver is another Ray job, whose workers take the place of this module's warm ones) ---


def _head(api, repo_id: str) -> str | None:
    return api.repo_info(repo_id).sha if api.repo_exists(repo_id) else None


def test_ctrl_c_cancels_a_ray_push_and_publishes_nothing(cluster, hub_module, tmp_path):
    """``push_env --backend=ray`` interrupted mid-run (SIGINT, as Ctrl-C sends): it exits promptly with a message,
    the Hub repo gets no commit, no staging folder is left, and no Ray worker keeps running a shard."""
    import re
    import shutil
    import subprocess
    import threading

    env_dir = tmp_path / "hover"
    shutil.copytree(ENVS / "hover", env_dir)
    files_before = sorted(p.relative_to(env_dir) for p in env_dir.rglob("*"))
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    repo = "ray/hover"  # published by the first case when it ran before (then it has a head to keep)
    head = _head(hub_module.api, repo)
    episodes = 400
    proc = subprocess.Popen(
        [sys.executable, "-m", "hub_envs.cli", "push", f"--env_dir={env_dir}", f"--repo_id={repo}", f"--episodes={episodes}",
         "--config.episode_length=60", "--determinism_steps=6", "--backend=ray", f"--ray_address={cluster.address}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, "TMPDIR": str(scratch)},
        # as from a terminal: `make test` runs its legs in the background (`&`), and a non-interactive shell starts
        # background commands with SIGINT ignored, which every process below inherits: Ctrl-C never reached the push
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    err = bytearray()

    def pump() -> None:
        while chunk := proc.stderr.read1(4096):
            err.extend(chunk)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        done = re.compile(rb"Generating %d episodes:.*?(\d+)/%d" % (episodes, episodes))
        deadline = time.monotonic() + 600  # a hang guard, not a timing
        sent_at = None
        while time.monotonic() < deadline and proc.poll() is None:
            counts = [int(n) for n in done.findall(bytes(err))]
            if counts and max(counts) >= episodes // 2:
                break  # past the middle without a worker seen running a shard: the assertion below says so
            if counts and max(counts) > 0 and _busy_workers():  # a process title changes when a task starts: look again
                sent_at = max(counts)
                break  # mid-run: episodes have come back from the workers, most are still to run, workers are running
            time.sleep(0.05)
        assert proc.poll() is None, "the push ended before it could be interrupted:\n" + err.decode(errors="replace")[-3000:]
        assert sent_at is not None, "no Ray worker was seen running a shard in the first half of the push"
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=120)  # a hang guard
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=10)
    text = err.decode(errors="replace")
    clues = [line for line in text.splitlines() if "ignored" in line or "KeyboardInterrupt" in line or "Traceback" in line]
    assert code == 130, f"SIGINT sent at {sent_at}/{episodes} episodes; exit {code}; {clues[:10]}\n" + text[-3000:]
    assert "interrupted (Ctrl-C)" in text and "published nothing" in text and "Traceback" not in text, text[-3000:]
    assert re.search(r"workers alive=\d+/\d+", text), text[-3000:]  # the progress bar's count of live Ray workers
    assert _head(hub_module.api, repo) == head  # no new commit
    assert sorted(p.relative_to(env_dir) for p in env_dir.rglob("*")) == files_before  # nothing written into the folder
    assert not list(scratch.glob("hub-envs-push-*"))  # the staging folder (and its partial dataset) is gone
    deadline = time.monotonic() + 60  # cancelled tasks' workers are killed: poll until they are gone (hang guard)
    while _busy_workers() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _busy_workers(), "a Ray worker still runs a shard of the interrupted push"
