"""A repo published on one stack reproduces exactly on the other: the project's promise, across versions.

``make test`` runs the suite in ``.venv`` (newest Python, lerobot 0.6, huggingface_hub 1.x) and in
``.venv-compat`` (Python 3.11, lerobot 0.4.4, huggingface_hub 0.35), and tells each leg where the other
venv's interpreter is (``HUB_ENVS_OTHER_PYTHON``). One loopback Hub serves both: each direction pushes
with one interpreter and reproduces with the other, each with its own ``HF_HOME`` (two machines, in
effect), through the real ``push_env`` and ``hub-envs reproduce`` command lines.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ENVS = Path(__file__).resolve().parents[1] / "envs"
OTHER = os.environ.get("HUB_ENVS_OTHER_PYTHON") or None

pytestmark = pytest.mark.skipif(
    OTHER is None, reason="needs the other stack's interpreter in HUB_ENVS_OTHER_PYTHON (make test sets it: scripts/test-legs)"
)


def _cli(python: str, args: list[str], *, endpoint: str, home: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGING_FACE_", "HUB_ENVS_"))}
    env.update(HF_ENDPOINT=endpoint, HF_HOME=str(home), HF_HUB_DISABLE_TELEMETRY="1", HF_HUB_DISABLE_PROGRESS_BARS="1")
    return subprocess.run([python, "-m", "hub_envs.cli", *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=900)


def _stack(python: str) -> str:
    return subprocess.run([python, "-m", "hub_envs._stack"], capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.parametrize("publisher", ["this stack", "the other stack"])
def test_a_repo_published_on_one_stack_reproduces_exactly_on_the_other(hub, tmp_path, publisher):
    pub, rep = (sys.executable, OTHER) if publisher == "this stack" else (OTHER, sys.executable)
    assert _stack(pub) != _stack(rep), "both legs run the same stack: nothing crosses"
    repo = f"xs/hover-{'here' if pub == sys.executable else 'other'}"

    pushed = _cli(
        pub,
        ["push", f"--env_dir={ENVS / 'hover'}", f"--repo_id={repo}", "--episodes=3", "--workers=1"],
        endpoint=hub.endpoint,
        home=tmp_path / "publisher-home",
        cwd=tmp_path,
    )
    assert pushed.returncode == 0, pushed.stdout[-3000:] + pushed.stderr[-3000:]
    sha = hub.api.repo_info(repo).sha

    out = tmp_path / "report"
    run = _cli(
        rep,
        ["reproduce", f"--repo_id={repo}", f"--revision={sha}", "--trust_remote_code=true", "--workers=1", f"--out={out}"],
        endpoint=hub.endpoint,
        home=tmp_path / "reproducer-home",
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert run.stdout.startswith(f"REPRODUCED: {repo}@{sha}"), run.stdout[-3000:]
    assert "reproduce exactly" in run.stdout  # tolerance 0: every observation, reward and state bit for bit

    report = json.loads((out / "report.json").read_text())
    assert report["reproduced"] is True
    prov = report["provenance"]
    assert prov["sha"] == sha
    published, here = prov["versions_published"], prov["versions_here"]
    for name in ("python", "lerobot", "torch", "numpy", "huggingface_hub", "pybullet", "gymnasium"):
        assert name in published and name in here, name
    # and the rest of the requirements' closure the publisher recorded (resolved), as it is where the env ran
    assert set(prov["closure_published"]) == set(prov["closure_here"]) and "cloudpickle" in prov["closure_published"]
    published, here = {**published, **prov["closure_published"]}, {**here, **prov["closure_here"]}
    differing = {k for k in published if published[k] != here.get(k)}
    assert {"python", "lerobot", "huggingface_hub"} <= differing
    assert set(prov["version_differences"]) == differing  # every difference is listed, and only those
    # ranked: the env's requirements, their dependencies, the simulator, numpy/gymnasium, then the stack
    drift = prov["version_drift"]
    assert {d["package"]: [d["published"], d["here"]] for d in drift} == prov["version_differences"]
    order = ["requirement", "dependency", "simulator", "worker", "stack"]
    ranks = [order.index(d["kind"]) for d in drift]
    kinds = {d["package"]: d["kind"] for d in drift}
    assert ranks == sorted(ranks) and kinds["lerobot"] == kinds["python"] == "stack"
    stack_line = next(line for line in run.stdout.splitlines() if line.strip().startswith("stack:"))
    assert all(f"{name} {published[name]} (published) vs {here[name]} (here" in stack_line for name in differing)
