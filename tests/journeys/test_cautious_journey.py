"""The cautious user's journey (issue 29): someone else publishes an env; you meet it untrusted, then reproduce it
sandboxed, in a venv of the publisher's package versions, through the real ``hub-envs`` command, and its code never
sees your Hub token.

Real parts only: a ``hub-envs serve`` with ``--token`` and a second account, ``push_env`` as the publisher (alice),
the ``hub-envs`` CLI in subprocesses as the user (bob, his token in ``HF_TOKEN`` and stored in ``$HF_HOME/token`` as
``hf auth login`` leaves it), uv building the venv, kernel namespaces and a memory cgroup around the worker. The env
is ``tests/fixtures/hostile_env``: a point mass that behaves (so it publishes and reproduces) and, when told, tries
what code you have not read might try.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import urlparse

import pytest

from hub_envs import errors, load_env, push_env
from hub_envs.isolation.sandbox import sandbox_support
from hub_envs.testing import HubServer, hub_environment

HOSTILE = Path(__file__).resolve().parents[1] / "fixtures" / "hostile_env"
ALICE = "hf_alice_publishes_0123456789"
BOB = "hf_bob_is_cautious_0123456789"

pytestmark = pytest.mark.skipif(sandbox_support().get("root") is not True, reason="sandbox=True needs root")


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``hub-envs ARGS`` as the user runs it: a fresh process with this environment (the Hub, bob's HF_HOME)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    return subprocess.run(
        [sys.executable, "-m", "hub_envs.cli", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=600
    )


def _probe(env, mode: str, arg=None):
    env.reset(seed=0, options={"mode": mode, "arg": arg})
    return env.step(env.action_space.sample())[4].get("probe")


def test_a_cautious_user_reproduces_someone_elses_env_sandboxed_with_the_publishers_versions(tmp_path):
    t0 = time.perf_counter()
    server = HubServer(tmp_path / "hub-data", token=ALICE, env={"HUB_ENVS_SERVER_USERS": f"bob:{BOB}"})
    try:
        # alice publishes (the server's owner account; her token, her machine)
        with hub_environment(server.endpoint, tmp_path / "alice" / "hf", token=ALICE):
            sha = push_env(HOSTILE, "alice/point-mass", episodes=2, progress=False, workers=1).sha
        ref = f"alice/point-mass@{sha}"
        flags = ["--isolation=venv", "--sandbox=true", "--versions=publisher"]

        # bob: his own HF_HOME, his token exported and stored
        bob_home = tmp_path / "bob" / "hf"
        with hub_environment(server.endpoint, bob_home, token=BOB):
            (bob_home / "token").write_text(BOB)
            venvs = Path(os.environ["HUB_ENVS_HOME"]) / "venvs"

            # 1. untrusted: refused with the consent message, the sandbox flags notwithstanding; nothing was built
            refused = _cli("load", f"--repo_id={ref}", *flags, cwd=tmp_path)
            assert refused.returncode == 1, refused.stdout + refused.stderr
            assert "UntrustedCodeError" in refused.stderr and "would run on this machine" in refused.stderr
            assert f"hub-envs trust {ref}" in refused.stderr and "nothing was imported" in refused.stderr
            assert not venvs.exists(), "a venv was built for code nobody consented to"

            # 2. consent given, for a sandboxed run in a venv of the publisher's versions: REPRODUCED
            out = tmp_path / "report"
            done = _cli(
                "reproduce", "--repo_id=alice/point-mass", f"--revision={sha}", "--trust_remote_code=true", *flags,
                "--workers=1", "--resamples=50", f"--out={out}", cwd=tmp_path,
            )  # fmt: skip
            assert done.returncode == 0, done.stdout + done.stderr
            assert done.stdout.startswith(f"REPRODUCED: {ref}"), done.stdout
            report = json.loads((out / "report.json").read_text())
            assert report["settings"]["isolation"] == "venv+sandbox+publisher", report["settings"]
            worker = report["provenance"]["worker"]
            assert str(venvs) in worker["venv"], worker  # the publisher's versions, in a venv of their own
            published = report["provenance"]["versions_published"]
            for name in ("numpy", "gymnasium"):
                assert worker["versions"][name] == published[name], (name, worker["versions"], published)
                assert name not in report["provenance"]["version_differences"]

            # 3. the env's code, run the same way, cannot read bob's token, nor reach the Hub with it
            loaded = load_env(ref, trust_remote_code=True, isolation="venv", sandbox=True, versions="publisher", check=False)
            env = loaded.make()
            try:
                assert _probe(env, "env", ["HF_TOKEN", "HUGGING_FACE_HUB_TOKEN"]) == {
                    "HF_TOKEN": None,
                    "HUGGING_FACE_HUB_TOKEN": None,
                }
                for path in (bob_home / "token", Path.home() / ".cache" / "huggingface" / "token"):
                    assert str(_probe(env, "read", str(path))).startswith("refused"), path
                url = urlparse(server.endpoint)
                assert _probe(env, "connect", [url.hostname, url.port]).startswith("refused")
            finally:
                env.close()
                loaded.unregister()
            with pytest.raises(errors.UntrustedCodeError):  # and nothing of this was remembered as trust
                load_env(ref, isolation="venv", sandbox=True, versions="publisher", check=False)
    finally:
        server.kill()
        server.remove_log()
    print(f"cautious journey: {time.perf_counter() - t0:.1f} s")
