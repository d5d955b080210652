"""The Ray backend's tests (``tests/ray_cases.py``), in a pytest process of their own.

After ``tests/ray_cases.py`` ran in this process, the rollout engine's forked worker processes used to die at
start (``BrokenProcessPool``) in every later test with ``workers > 1``: the cluster's node objects outlived it
in Ray's ``atexit`` hooks, and a forked child crashed destroying their GCS clients (``ray_cases._release_gcs_clients``
now destroys them in the parent; ``pytest tests/ray_cases.py hub_envs/harness/rollout.py -k "eval_metrics or
rollout"`` passes). The cases still run in a child pytest (same interpreter, same conftest and fixtures, a
real Ray cluster on 127.0.0.1): whatever else Ray leaves in a process stays out of the rest of the suite.
"""

from __future__ import annotations

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
from helpers import RAY, ray_installed

HERE = Path(__file__).resolve().parent


needs_ray = pytest.mark.skipif(
    not ray_installed(),
    reason="ray is not installed in this Python (pip install 'hub-envs[ray]'): starts a real `ray start` head",
)


@pytest.mark.timeout(1500)  # the child's own cases have the suite's 600 s each; on a saturated machine all of them take longer
def test_the_ray_backend_cases_pass_in_their_own_process():
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rA", str(HERE / "ray_cases.py")],
        cwd=HERE.parent,
        env={**os.environ, "RAY_DEDUP_LOGS": "0"},
        capture_output=True,
        text=True,
        timeout=1500,
    )
    summary = [line for line in result.stdout.splitlines() if line.startswith(("PASSED", "FAILED", "ERROR"))]
    assert result.returncode == 0, result.stdout[-8000:] + "\n" + result.stderr[-4000:]
    cases = (HERE / "ray_cases.py").read_text().count("\ndef test_")
    assert len([s for s in summary if s.startswith("PASSED")]) == cases, summary  # every case ran, none skipped


def test_backend_ray_without_ray_installed_fails_first_with_the_pip_line(tmp_path):
    """A user without the ``ray`` extra asking for ``--backend=ray`` gets the typed error and the pip line before
    any work: nothing built, nothing published (the push never reaches the Hub: the endpoint is a closed port).
    Ray is hidden the way CPython blocks an import (``sys.modules["ray"] = None``), in a process of its own."""
    env_dir = tmp_path / "pendulum"
    shutil.copytree(HERE.parent / "envs" / "pendulum", env_dir)
    files_before = sorted(p.relative_to(env_dir) for p in env_dir.rglob("*"))
    code = "import sys; sys.modules['ray'] = None\nfrom hub_envs.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            code,
            "push",
            f"--env_dir={env_dir}",
            "--repo_id=nobody/pendulum",
            "--episodes=2",
            "--backend=ray",
        ],
        cwd=tmp_path,
        env={**os.environ, "HF_ENDPOINT": "http://127.0.0.1:9", "HF_HOME": str(tmp_path / "hf"), "TMPDIR": str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode != 0
    assert "pip install 'hub-envs[ray]'" in result.stderr and "--backend=local" in result.stderr, result.stderr[-2000:]
    assert "Traceback" not in result.stderr, result.stderr[-2000:]
    assert "Generating" not in result.stderr  # no episode was run first
    assert sorted(p.relative_to(env_dir) for p in env_dir.rglob("*")) == files_before
    assert not list(tmp_path.glob("hub-envs-push-*"))


# --- a driver whose Ray setting differs from the cluster's -----------------------------------------


class LoopbackHead:
    """A Ray head started with ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 ray start --head``, as on a laptop or a one-machine
    setup: its node address is 127.0.0.1 and its GCS listens there only. Token authentication on (Ray 2.60's default
    once a token is in ``~/.ray/auth_token``), its own home and temp folder. :meth:`stop` kills what it started: its
    process group and every process using its folder (never ``ray stop``, which stops every Ray of this machine)."""

    def __init__(self) -> None:
        # short: Ray's unix socket paths under the temp folder must fit in 107 bytes
        self.root = Path(tempfile.mkdtemp(prefix="hubenvs-lo-", dir="/tmp" if os.path.isdir("/tmp") else None))
        self.token = secrets.token_hex(32)
        self.group: int | None = None
        (self.root / "home" / ".ray").mkdir(parents=True)
        (self.root / "home" / ".ray" / "auth_token").write_text(self.token)
        env = {k: os.environ[k] for k in ("PATH", "LANG", "LC_ALL", "PYTHONPATH") if k in os.environ}
        env.update(
            HOME=str(self.root / "home"),
            RAY_AUTH_MODE="token",
            RAY_USAGE_STATS_ENABLED="0",
            RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0",
        )
        cmd = [RAY, "start", "--head", "--port=0", "--include-dashboard=false", "--num-cpus=1", "--disable-usage-stats"]
        cmd += [f"--object-store-memory={80 * 2**20}", "--dashboard-agent-listen-port=0", f"--temp-dir={self.root / 'tmp'}"]
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        self.group = proc.pid  # the daemons it starts stay in its process group after it exits
        out, _ = proc.communicate(timeout=300)  # a hang guard
        if proc.returncode != 0:
            self.stop()
            raise AssertionError(f"ray start --head failed:\n{out.decode(errors='replace')[-3000:]}")
        self.address = (self.root / "tmp" / "ray_current_cluster").read_text().strip()

    def _pids(self) -> list[int]:
        """The processes whose command line names this head's folder (its daemons), and their descendants."""
        marker, parents, found = str(self.root).encode(), {}, set()
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
                parents[int(pid)] = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if marker in cmd and int(pid) != os.getpid():
                found.add(int(pid))
        while new := {pid for pid, parent in parents.items() if parent in found} - found:
            found |= new
        return sorted(found)

    def stop(self) -> None:
        """SIGKILL to the head's process group and to every process of its folder; the folder removed."""
        for _ in range(2):  # twice: a process could have been starting during the first round
            for pid in self._pids():
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            if self.group is not None:
                try:
                    os.killpg(self.group, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + 10  # a hang guard: killed processes are gone once reaped
            while time.monotonic() < deadline and self._pids():
                time.sleep(0.05)
        shutil.rmtree(self.root, ignore_errors=True)


@pytest.fixture
def loopback_head():
    head = LoopbackHead()
    try:
        yield head
    finally:
        head.stop()


@needs_ray
@pytest.mark.timeout(600)
def test_a_driver_without_the_clusters_loopback_setting_fails_with_a_typed_error_instead_of_hanging(loopback_head, hub, tmp_path):
    """A cluster started with ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` listens on 127.0.0.1 only; a driver without that
    setting (Linux's default) is given 127.0.0.1:PORT, and Ray's ``ray.init`` replaces it by this machine's outward
    address, where nothing listens, and retries "Failed to connect to GCS" for about 14 minutes (no error, no exit).
    ``hub-envs push --backend=ray`` must instead exit with ``ClusterUnreachableError``, naming the address and the
    setting, before any work: a hang past 180 s (the subprocess' timeout) fails the test."""
    env_dir = tmp_path / "tiny"
    shutil.copytree(HERE / "fixtures" / "tiny_env", env_dir)
    token_file = tmp_path / "ray-token"
    token_file.write_text(loopback_head.token)
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "RAY_ADDRESS", "RAY_AUTH_TOKEN")}
    env.update(HOME=str(tmp_path / "user-home"), RAY_AUTH_MODE="token", RAY_AUTH_TOKEN_PATH=str(token_file), TMPDIR=str(tmp_path))
    cmd = [sys.executable, "-m", "hub_envs.cli", "push", f"--env_dir={env_dir}", "--repo_id=lo/tiny", "--episodes=2"]
    cmd += ["--backend=ray", f"--ray_address={loopback_head.address}"]
    try:
        result = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=180, cwd=tmp_path)
    except subprocess.TimeoutExpired as exc:
        said = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else exc.stderr or ""
        pytest.fail(f"hub-envs push --backend=ray hung past 180 s against {loopback_head.address}:\n{said[-3000:]}")
    assert result.returncode == 1, result.stderr[-3000:]
    err = result.stderr
    assert "error: ClusterUnreachableError:" in err and loopback_head.address in err, err[-3000:]
    assert "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0" in err, err[-3000:]  # what to set to reach this cluster
    assert "Traceback" not in err and "Generating" not in err, err[-3000:]  # failed first: no episode ran
    assert not hub.api.repo_exists("lo/tiny")  # nothing published
