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
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


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
