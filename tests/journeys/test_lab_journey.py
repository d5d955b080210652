"""The lab journey: a Hub with a token, a private env repo, and a Ray cluster someone else started.

A lab runs ``hub-envs serve --token``; an admin starts Ray on the machines with ``ray start`` from a shell that knows
nothing of the Hub (no ``HF_*``, no ``HUB_ENVS_*``), with Ray's token authentication. A user pushes a private env,
is told what to set for the cluster's authentication, then runs ``hub-envs reproduce --backend=ray`` and
``push_env --backend=ray`` against the cluster: the results are the local backend's, byte for byte, and the
workers reached the Hub with the endpoint and token of the run, not of their nodes.

The cluster is two real ``ray start`` nodes on this machine's address (a head, and a second node joining it with
``--address``), each with its own home and temp folder and one CPU. :class:`RayNodes` stops both in the fixture's
teardown whatever the test did: their process groups, then any process still using their folders.
"""

from __future__ import annotations

import atexit
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from helpers import RAY, TINY, ray_installed

from hub_envs import push_env, reproduce
from hub_envs.testing import HubServer, hub_environment

pytestmark = pytest.mark.skipif(
    not ray_installed(),
    reason="ray is not installed in this Python (pip install 'hub-envs[ray]'): the lab journey starts real `ray start` nodes",
)
HUB_TOKEN = "hf_lab_journey_token"
REPO = "lab/tiny"
PUSH = {"episodes": 4, "determinism_steps": 6}


# --- the cluster an admin started ----------------------------------------------------------------


def _admin_env(home: Path) -> dict[str, str]:
    """The environment of an admin's shell on a node: no Hub settings at all (no ``HF_*``, ``HUB_ENVS_*``), hub-envs
    installed (``PYTHONPATH`` when the tests run from a checkout), Ray's token authentication on."""
    env = {k: os.environ[k] for k in ("PATH", "LANG", "LC_ALL", "PYTHONPATH") if k in os.environ}
    env.update(
        HOME=str(home),  # the node's own ~/.ray/auth_token and ~/.cache/huggingface
        RAY_AUTH_MODE="token",
        RAY_USAGE_STATS_ENABLED="0",
    )
    return env


class RayNodes:
    """A Ray head and a second node started with ``ray start``, as an admin starts them: each in a process group of
    its own, with its own home (holding the cluster's token) and temp folder."""

    def __init__(self) -> None:
        # short: Ray's unix socket paths under the temp folder must fit in 107 bytes
        self.root = Path(tempfile.mkdtemp(prefix="hubenvs-lab-", dir="/tmp" if os.path.isdir("/tmp") else None))
        self.token = secrets.token_hex(32)  # what `ray get-auth-token --generate` writes
        self.groups: list[int] = []
        self.address: str | None = None
        atexit.register(self.stop)  # a backstop: the fixture's teardown stops them first

    def home(self, node: str) -> Path:
        return self.root / node / "home"

    def start(self) -> RayNodes:
        for node in ("head", "worker"):
            (self.home(node) / ".ray").mkdir(parents=True)
            (self.home(node) / ".ray" / "auth_token").write_text(self.token)
        self._ray_start("head", "--head", "--port=0", "--include-dashboard=false")
        self.address = (self.root / "head" / "tmp" / "ray_current_cluster").read_text().strip()
        self._ray_start("worker", f"--address={self.address}")  # returns once the node is registered with the head
        return self

    def _ray_start(self, node: str, *args: str) -> None:
        # on this machine's own address, as on a real cluster; every port but the head's GCS (printed, read back) free
        cmd = [RAY, "start", *args, "--num-cpus=1", f"--object-store-memory={80 * 2**20}", "--disable-usage-stats"]
        cmd += ["--dashboard-agent-listen-port=0", f"--temp-dir={self.root / node / 'tmp'}"]
        proc = subprocess.Popen(
            cmd, env=_admin_env(self.home(node)), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True
        )
        self.groups.append(proc.pid)  # the daemons it starts stay in its process group after it exits
        out, _ = proc.communicate(timeout=300)  # a hang guard
        assert proc.returncode == 0, f"ray start ({node}) failed:\n{out.decode(errors='replace')[-3000:]}"

    def raylet_environ(self, node: str) -> dict[str, str]:
        """The environment of a node's raylet: what the node's worker processes start from."""
        for pid in _pids_using(self.root / node):
            if Path(f"/proc/{pid}/exe").resolve().name == "raylet":
                raw = Path(f"/proc/{pid}/environ").read_bytes()
                return dict(item.split("=", 1) for item in raw.decode(errors="replace").split("\0") if "=" in item)
        raise AssertionError(f"no raylet runs for the {node} node")

    def stop(self) -> None:
        """SIGKILL to both process groups (the daemons and the workers they started) and to every process using the
        cluster's folders or descending from one (found first: a killed daemon's children lose their parent); the
        folders are removed. Not SIGTERM: Ray's GCS and raylet take over 10 s to drain on it, and this cluster is
        thrown away."""
        for _ in range(2):  # twice: a process could have been starting while the first round ran
            stragglers = _pids_using(self.root)
            for group in self.groups:
                try:
                    os.killpg(group, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            for pid in stragglers:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + 10  # a hang guard: killed processes are gone once they are reaped
            while time.monotonic() < deadline and any(_group_alive(g) for g in self.groups):
                time.sleep(0.05)
        shutil.rmtree(self.root, ignore_errors=True)
        atexit.unregister(self.stop)


def _group_alive(group: int) -> bool:
    """Whether a process of the group still runs (a zombie waiting to be reaped by init does not)."""
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            state, _, pgrp = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[:3]
        except (OSError, ValueError):
            continue
        if int(pgrp) == group and state != "Z":
            return True
    return False


def _pids_using(folder: Path) -> list[int]:
    """Processes whose command line names ``folder`` (a node's daemons), and their descendants (its workers)."""
    marker, parents, found = str(folder).encode(), {}, set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
            parents[int(pid)] = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        if marker in cmd and int(pid) != os.getpid():
            found.add(int(pid))
    grown = True
    while grown:
        new = {pid for pid, parent in parents.items() if parent in found} - found
        found |= new
        grown = bool(new)
    return sorted(found)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """``hub-envs serve --token``, the user's client environment pointed at it, and the admin's two Ray nodes."""
    root = tmp_path_factory.mktemp("lab")
    nodes = RayNodes()
    with HubServer(root / "hub-data", token=HUB_TOKEN) as server:
        try:
            nodes.start()
            with hub_environment(server.endpoint, root / "hf-user", token=HUB_TOKEN):
                yield server, nodes, root
        finally:
            nodes.stop()


def _cli(*args: str, root: Path, nodes: RayNodes, auth: bool = True) -> subprocess.CompletedProcess:
    """A hub-envs command as the user runs it: the user's Hub settings (set by ``hub_environment``), and for Ray the
    cluster's token (``RAY_AUTH_MODE=token``, the token in a file) unless ``auth`` is False."""
    env = {**os.environ, "HOME": str(root / "user-home")}
    for var in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH", "RAY_ADDRESS"):
        env.pop(var, None)
    if auth:
        token_file = root / "ray-token"
        token_file.write_text(nodes.token)
        env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN_PATH=str(token_file))
    return subprocess.run(
        [sys.executable, "-m", "hub_envs.cli", *args], env=env, capture_output=True, text=True, timeout=900, cwd=root
    )


def _comparable(report: dict) -> dict:
    """A report.json minus what differs between identical runs (wall-clock times, where the episodes ran)."""
    report["provenance"].pop("generated_at")
    report["replay"].pop("seconds")
    for bench in report["benchmarks"]:
        bench.pop("seconds")
    report.pop("settings")
    report.pop("timings")
    return report


# --- the journey --------------------------------------------------------------------------------


def test_a_lab_reproduces_and_pushes_a_private_env_on_a_cluster_an_admin_started(lab):
    server, nodes, root = lab
    from huggingface_hub import HfApi

    # the user publishes a private env and reproduces it on this machine: the reference
    local = push_env(TINY, REPO, private=True, backend="local", workers=1, progress=False, **PUSH)
    assert not HfApi(endpoint=server.endpoint, token=False).repo_exists(REPO)  # private: nobody without the token sees it
    ref = reproduce(f"{REPO}@{local.sha}", trust_remote_code=True, workers=1, out=root / "local", progress=False)
    assert ref.reproduced

    # the nodes were started without any Hub setting: the Hub and its token can only reach their workers with the run
    for node in ("head", "worker"):
        assert not [k for k in nodes.raylet_environ(node) if k.startswith(("HF_", "HUGGING", "HUB_ENVS_"))]

    # the cluster uses token authentication: without RAY_AUTH_MODE=token the user is told what to set, at once
    refused = _cli("reproduce", f"--repo_id={REPO}", f"--revision={local.sha}", "--trust_remote_code=true",
                   "--backend=ray", f"--ray_address={nodes.address}", root=root, nodes=nodes, auth=False)  # fmt: skip
    assert refused.returncode != 0 and "Traceback" not in refused.stderr, refused.stderr[-3000:]
    assert "uses token authentication" in refused.stderr and "RAY_AUTH_MODE=token" in refused.stderr, refused.stderr[-3000:]

    # with it: the reproduction on Ray is the local one (timings and backend aside)
    done = _cli("reproduce", f"--repo_id={REPO}", f"--revision={local.sha}", "--trust_remote_code=true",
                "--backend=ray", f"--ray_address={nodes.address}", f"--out={root / 'ray'}", root=root, nodes=nodes)  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-4000:]
    on_ray = json.loads((root / "ray" / "report.json").read_text())
    assert on_ray["settings"]["backend"] == "ray"
    assert _comparable(on_ray) == _comparable(json.loads((root / "local" / "report.json").read_text()))
    assert on_ray["replay"]["episodes"], on_ray["replay"]
    # both nodes' workers downloaded the private repo into their own node's cache, with the run's endpoint and token
    for node in ("head", "worker"):
        assert (nodes.home(node) / ".cache" / "huggingface" / "hub" / "models--lab--tiny" / "snapshots" / local.sha).is_dir()
    # the Hub token went with the run's data, not into what the cluster writes down (its logs, its job records)
    written = [p for p in nodes.root.rglob("*") if p.is_file() and p.stat().st_size < 50 * 2**20]
    assert not [p for p in written if HUB_TOKEN.encode() in p.read_bytes()]

    # the same env pushed again on Ray: the dataset generated there is byte-identical (no new commit, same files)
    pushed = _cli("push", f"--env_dir={TINY}", f"--repo_id={REPO}", "--private=true", "--force=true", "--backend=ray",
                  f"--ray_address={nodes.address}", *[f"--{k}={v}" for k, v in PUSH.items()], root=root, nodes=nodes)  # fmt: skip
    assert pushed.returncode == 0, pushed.stdout[-2000:] + pushed.stderr[-4000:]
    assert f"Unchanged; already published {REPO}" in pushed.stdout and local.sha in pushed.stdout, pushed.stdout[-2000:]
    api = HfApi(endpoint=server.endpoint, token=HUB_TOKEN)
    assert api.repo_info(REPO).sha == local.sha
    dataset = {p: h for p, h in local.manifest.files.items() if p.startswith("dataset/")}
    assert any(p.startswith("dataset/data/") for p in dataset)
    manifest = json.loads(Path(api.hf_hub_download(REPO, "hub_env.json", revision=local.sha)).read_text())
    assert {p: h for p, h in manifest["files"].items() if p.startswith("dataset/")} == dataset
