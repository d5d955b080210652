"""A hostile env repo against ``sandbox=True`` and ``isolation="venv"``: what a red-team got through (issue 30).

Each test replays one finding on the real loopback Hub, real uv and real worker processes: a repo that makes the
venv build run its code outside the sandbox (a direct reference, an sdist, a smuggled uv option, a wheel's ``.pth``),
a sandbox that shows ``HF_HOME`` or the calling script's ``.env``, a memory limit that forked children go around,
and an env whose exception and stderr carry terminal escape sequences. Where code could run outside the sandbox,
the payload writes a marker file, so "nothing ran" is a fact the test checks.

The packages the payloads pose as are ``cloudpickle`` (a dependency of gymnasium) at a version PyPI does not have
(9.9.9): uv looks it up where it looks up gymnasium's dependencies anyway, then finds it in a local folder
(``UV_FIND_LINKS``, uv's own setting, which hub-envs passes to uv).
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

import pytest
from helpers import FIXTURES, republish

from hub_envs import errors, load_env, push_env
from hub_envs.isolation import sandbox as sandbox_module
from hub_envs.isolation.proxy import IsolatedEnv

HOSTILE = FIXTURES / "hostile_env"
TOKEN = "hf_the_users_own_token_0123456789"

pytestmark = pytest.mark.skipif(
    sandbox_module.sandbox_support().get("root") is not True, reason="sandbox=True needs root (it is refused otherwise)"
)


@pytest.fixture(scope="module")
def hostile(hub_module) -> str:
    """The hostile env (tests/fixtures/hostile_env), published once: ``repo@sha``."""
    result = push_env(HOSTILE, "box/hostile", episodes=1, progress=False, workers=1)
    return f"box/hostile@{result.sha}"


@pytest.fixture
def user_token(monkeypatch) -> str:
    """The caller holds a Hub token, as a user who ran ``hf auth login`` or exported HF_TOKEN does."""
    monkeypatch.setenv("HF_TOKEN", TOKEN)
    return TOKEN


def _inner(env) -> IsolatedEnv:
    assert isinstance(env.unwrapped, IsolatedEnv), env
    return env.unwrapped


def _probe(env, mode: str, arg=None):
    env.reset(seed=0, options={"mode": mode, "arg": arg})
    return env.step(env.action_space.sample())[4].get("probe")


def _marker_backend(marker: Path) -> str:
    """A PEP 517 build backend (in the project itself: ``backend-path``) that records it ran, and what it saw."""
    return (
        "import os\n"
        "def _mark(hook):\n"
        f"    with open({str(marker)!r}, 'a') as f:\n"
        "        f.write(f\"{hook} HF_TOKEN={os.environ.get('HF_TOKEN')}\\n\")\n"
        "def get_requires_for_build_wheel(config_settings=None):\n"
        "    _mark('get_requires_for_build_wheel')\n"
        "    return []\n"
        "def get_requires_for_build_sdist(config_settings=None):\n"
        "    return []\n"
        "def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):\n"
        "    _mark('prepare_metadata_for_build_wheel')\n"
        "    raise RuntimeError('the probe builds nothing')\n"
        "def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):\n"
        "    _mark('build_wheel')\n"
        "    raise RuntimeError('the probe builds nothing')\n"
    )


def _probe_project(folder: Path, marker: Path, version: str = "9.9.9") -> Path:
    """A source project posing as cloudpickle whose build code writes ``marker``."""
    folder.mkdir(parents=True)
    (folder / "pyproject.toml").write_text(
        '[build-system]\nrequires = []\nbuild-backend = "probe_backend"\nbackend-path = ["."]\n\n'
        f'[project]\nname = "cloudpickle"\nversion = "{version}"\n'
    )
    (folder / "probe_backend.py").write_text(_marker_backend(marker))
    return folder


def _probe_sdist(links: Path, marker: Path, version: str = "9.9.9") -> Path:
    """``links/cloudpickle-<version>.tar.gz``: an sdist whose build code writes ``marker``."""
    project = _probe_project(links.parent / f"sdist-src-{version}", marker, version)
    links.mkdir(parents=True, exist_ok=True)
    sdist = links / f"cloudpickle-{version}.tar.gz"
    with tarfile.open(sdist, "w:gz") as tar:
        tar.add(project, arcname=f"cloudpickle-{version}")
    return sdist


def _trojan_wheel(links: Path, marker: Path, version: str = "9.9.9") -> Path:
    """``links/cloudpickle-<version>-py3-none-any.whl``: the real cloudpickle package, plus a ``.pth`` file (which
    Python runs at every start of the interpreter it is installed for) that writes ``marker``."""
    import cloudpickle

    files: dict[str, bytes] = {}
    package = Path(cloudpickle.__file__).parent
    for path in sorted(package.rglob("*.py")):
        files[f"cloudpickle/{path.relative_to(package)}"] = path.read_bytes()
    files["zz_probe_hook.py"] = (
        "import os\n"
        "try:\n"
        f"    with open({str(marker)!r}, 'a') as f:\n"
        "        f.write(f\"pth ran, HF_TOKEN={os.environ.get('HF_TOKEN')}\\n\")\n"
        "except OSError:\n"
        "    pass\n"
    ).encode()
    files["zz_probe.pth"] = b"import zz_probe_hook\n"
    info = f"cloudpickle-{version}.dist-info"
    files[f"{info}/METADATA"] = f"Metadata-Version: 2.1\nName: cloudpickle\nVersion: {version}\n\n".encode()
    files[f"{info}/WHEEL"] = b"Wheel-Version: 1.0\nGenerator: hub-envs-test\nRoot-Is-Purelib: true\nTag: py3-none-any\n\n"
    record = []
    for name, data in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{name},sha256={digest},{len(data)}")
    files[f"{info}/RECORD"] = ("\n".join(record + [f"{info}/RECORD,,"]) + "\n").encode()
    links.mkdir(parents=True, exist_ok=True)
    wheel = links / f"cloudpickle-{version}-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return wheel


def _with_requirements(api, hostile: str, extra: list[str], edit=None) -> str:
    """Re-publish the hostile env's first commit (``hostile``: ``repo@sha``) with ``extra`` requirements in its
    manifest (and ``edit(manifest)``): the new sha."""
    from huggingface_hub import hf_hub_download

    repo, sha = hostile.split("@")
    original = json.loads(Path(hf_hub_download(repo, "hub_env.json", revision=sha, endpoint=api.endpoint)).read_text())

    def change(folder: Path) -> None:
        manifest = dict(original, requirements=list(original["requirements"]) + list(extra))
        if edit is not None:
            edit(manifest)
        (folder / "hub_env.json").write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")

    return f"{repo}@{republish(api, repo, change)}"


# --- issue 30 item 2: the venv build runs no code of the repo's choosing outside the sandbox ------------------


@pytest.mark.parametrize("sandbox", [True, False], ids=["sandbox", "venv-only"])
def test_a_direct_reference_requirement_is_refused_before_anything_is_built(hostile, hub_module, user_token, tmp_path, sandbox):
    """``cloudpickle @ file:///...`` (a URL or a git repo would do the same): uv would build that project, running its
    build code as the caller, with HF_TOKEN and the network, before any sandbox exists."""
    marker = tmp_path / "build-ran"
    project = _probe_project(tmp_path / "payload", marker)
    ref = _with_requirements(hub_module.api, hostile, [f"cloudpickle @ {project.as_uri()}"])
    with pytest.raises(errors.VenvBuildError) as info:
        load_env(ref, trust_remote_code=True, isolation="venv", sandbox=sandbox, check=False)
    assert not marker.exists(), f"the repo's build code ran outside the sandbox: {marker.read_text()}"
    assert "direct reference" in str(info.value) and "cloudpickle @ file://" in str(info.value)
    assert "Nothing was installed" in str(info.value)


def test_publisher_constraints_cannot_smuggle_uv_options(hostile, hub_module, user_token, tmp_path):
    """``versions="publisher"`` writes the manifest's ``resolved`` into uv's constraints file: a version holding a
    newline added ``--find-links`` to it, and uv built the payload from there (with HF_TOKEN), outside the sandbox."""
    marker = tmp_path / "build-ran"
    links = tmp_path / "links"
    _probe_sdist(links, marker)

    def smuggle(manifest):
        manifest["resolved"] = dict(manifest["resolved"], cloudpickle=f"9.9.9\n--find-links {links}")

    ref = _with_requirements(hub_module.api, hostile, [], smuggle)
    with pytest.raises(errors.VenvBuildError) as info:
        load_env(ref, trust_remote_code=True, isolation="venv", sandbox=True, versions="publisher", check=False)
    assert not marker.exists(), f"the repo's build code ran outside the sandbox: {marker.read_text()}"
    assert "hub_env.json resolved['cloudpickle']" in str(info.value) and "is not a version" in str(info.value)

    def bad_pin(manifest):  # a recorded version becomes an ``==`` pin on uv's command line: checked the same way
        manifest["versions"] = dict(manifest["versions"], gymnasium="1.0 @ file:///etc")

    ref = _with_requirements(hub_module.api, hostile, [], bad_pin)
    with pytest.raises(errors.VenvBuildError, match=r"versions\['gymnasium'\]"):
        load_env(ref, trust_remote_code=True, isolation="venv", sandbox=True, versions="publisher", check=False)

    def odd_python(manifest):  # the publisher's Python becomes an argument of `uv python find`: a version only
        manifest["versions"] = dict(manifest["versions"], python="/opt/elsewhere/python")

    ref = _with_requirements(hub_module.api, hostile, [], odd_python)
    with pytest.raises(errors.VenvBuildError, match=r"versions\['python'\]"):
        load_env(ref, trust_remote_code=True, isolation="venv", sandbox=True, versions="publisher", check=False)


def test_a_sandboxed_venv_builds_nothing_from_source(hostile, hub_module, user_token, tmp_path, monkeypatch):
    """A requirement the index (here: a local folder uv is told about) has only as an sdist: building it runs its
    code, which with ``sandbox=True`` must not happen outside the sandbox; the refusal says how to get a wheel."""
    marker = tmp_path / "build-ran"
    links = tmp_path / "links"
    _probe_sdist(links, marker)
    monkeypatch.setenv("UV_FIND_LINKS", str(links))
    ref = _with_requirements(hub_module.api, hostile, ["cloudpickle==9.9.9"])
    with pytest.raises(errors.VenvBuildError) as info:
        load_env(ref, trust_remote_code=True, isolation="venv", sandbox=True, check=False)
    assert not marker.exists(), f"an sdist's build code ran outside the sandbox: {marker.read_text()}"
    assert "only wheels are installed" in str(info.value) and "cloudpickle" in str(info.value)


def test_a_venv_build_never_sees_the_callers_token(hostile, hub_module, user_token, tmp_path, monkeypatch):
    """Without the sandbox a build from source is allowed (the user consented to the repo's code), but the build
    runs without the caller's tokens: HF_TOKEN never reaches a build backend."""
    marker = tmp_path / "build-ran"
    links = tmp_path / "links"
    _probe_sdist(links, marker)
    monkeypatch.setenv("UV_FIND_LINKS", str(links))
    ref = _with_requirements(hub_module.api, hostile, ["cloudpickle==9.9.9"])
    with pytest.raises(errors.VenvBuildError):  # the probe's backend refuses to build
        load_env(ref, trust_remote_code=True, isolation="venv", check=False)
    seen = marker.read_text()  # it ran: consent covers that
    assert "HF_TOKEN=None" in seen and user_token not in seen


def test_a_wheels_pth_file_never_runs_outside_the_sandbox(hostile, hub_module, user_token, tmp_path, monkeypatch):
    """A wheel (no build at all) may install a ``.pth`` file, which runs at every start of the venv's interpreter:
    uv's bytecode compilation started it outside the sandbox, with HF_TOKEN. Inside the sandbox it may run: it
    cannot reach the file it writes, and the env works."""
    marker = tmp_path / "pth-ran"
    links = tmp_path / "links"
    _trojan_wheel(links, marker)
    monkeypatch.setenv("UV_FIND_LINKS", str(links))
    ref = _with_requirements(hub_module.api, hostile, ["cloudpickle==9.9.9"])
    loaded = load_env(ref, trust_remote_code=True, isolation="venv", sandbox=True, check=False)
    assert not marker.exists(), f"a wheel's .pth file ran outside the sandbox: {marker.read_text()}"
    env = loaded.make()
    try:
        assert _probe(env, "env", ["HF_TOKEN"]) == {"HF_TOKEN": None}
        assert (
            "cloudpickle==9.9.9"
            in json.loads((Path(_probe(env, "versions")["prefix"]) / "hub-envs-venv.json").read_text())["installed"]
        )
    finally:
        env.close()
        loaded.unregister()
    assert not marker.exists(), f"a wheel's .pth file wrote outside the sandbox: {marker.read_text()}"


# --- issue 30 item 3: nothing of the caller's files but what imports the env -------------------------------


def _lab_folder():
    """A folder outside home and the temp folders (as ``/data`` or ``/scratch`` on a lab machine), world-readable."""
    home = os.path.realpath(os.path.expanduser("~"))
    for parent in ("/srv", "/mnt", "/opt", "/var/lib"):
        if os.path.isdir(parent) and os.access(parent, os.W_OK) and not parent.startswith(home):
            folder = Path(tempfile.mkdtemp(prefix="hub-envs-lab-", dir=parent))
            folder.chmod(0o755)
            return folder
    return None


@pytest.fixture
def lab(monkeypatch):
    """``HF_HOME`` (with a stored token) and ``HUB_ENVS_HOME`` outside home and /tmp, and the calling script's folder
    there too, with a ``.env`` of secrets; that folder on ``sys.path`` as a script's own folder is."""
    folder = _lab_folder()
    if folder is None:
        pytest.skip("no writable folder outside home and /tmp to play a lab machine's /data")
    try:
        hf_home, state, project = folder / "hf", folder / "hub-envs-state", folder / "project"
        for d in (hf_home, state, project):
            d.mkdir()
            d.chmod(0o755)
        (hf_home / "token").write_text(TOKEN)
        (state / "notes.json").write_text('{"secret": "what hub-envs keeps"}')
        (project / ".env").write_text("AWS_SECRET_ACCESS_KEY=lab-secret\n")
        (project / "train.py").write_text("print('the script')\n")
        for f in (hf_home / "token", state / "notes.json", project / ".env", project / "train.py"):
            f.chmod(0o644)  # as a umask of 022 leaves them
        monkeypatch.setenv("HF_HOME", str(hf_home))
        monkeypatch.setenv("HUB_ENVS_HOME", str(state))
        monkeypatch.syspath_prepend(str(project))
        yield {"root": folder, "token": hf_home / "token", "trust": state / "notes.json", "env": project / ".env"}
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.mark.parametrize("isolation", ["process", "venv"])
def test_the_sandbox_shows_no_hf_home_hub_envs_home_or_script_folder(hostile, lab, isolation):
    loaded = load_env(hostile, trust_remote_code=True, isolation=isolation, sandbox=True, check=False)
    env = loaded.make()
    try:
        for secret in (lab["token"], lab["trust"], lab["env"]):
            assert _probe(env, "read", str(secret)).startswith("refused"), f"the sandboxed env read {secret}"
        # at most the way to the env's venv (under HUB_ENVS_HOME) is there, as empty folders: nothing else of the lab's
        shown = _probe(env, "listdir", str(lab["root"]))
        assert str(shown).startswith("refused") or (isolation == "venv" and shown == ["hub-envs-state"]), shown
        if isolation == "venv":
            assert _probe(env, "listdir", str(lab["trust"].parent)) == ["venvs"]
        # the env itself works: it imports and steps from what the sandbox does show
        env.reset(seed=0)
        assert env.observation_space.contains(env.step(env.action_space.sample())[0])
    finally:
        env.close()
        loaded.unregister()


# --- issue 30 item 4: one memory limit for the whole sandbox ----------------------------------------------------


def test_the_memory_limit_covers_every_process_of_the_sandbox_together(hostile):
    """Five forked children of 150 MB each under a 512 MB limit: each stayed under the per-process limit, and all
    together held 750 MB. Now the sandbox is stopped and says why; where no memory cgroup can be made here, the
    limit asked for is refused instead of being silently per process."""
    support = sandbox_module.sandbox_support()
    if "memory cgroup" in support and support["memory cgroup"] is not True:  # none can be made on this machine
        with pytest.raises(errors.SandboxUnavailableError, match="memory cgroup"):
            load_env(hostile, trust_remote_code=True, sandbox=True, check=False, sandbox_limits={"memory_mb": 512})
        return
    loaded = load_env(
        hostile,
        trust_remote_code=True,
        sandbox=True,
        check=False,
        step_timeout=60,
        restart=True,
        sandbox_limits={"memory_mb": 512},
    )
    env = loaded.make()
    try:
        worker = _inner(env).worker
        env.reset(seed=0, options={"mode": "forkmem", "arg": [5, 150]})
        with pytest.raises(errors.EnvCrashedError, match="memory limit of 512 MB") as info:
            env.step(env.action_space.sample())
        assert "all its processes together" in str(info.value) and hostile.split("@")[0] in str(info.value)
        cgroup = worker.cgroup.path
        env.reset(seed=1)  # restart=True: a fresh sandbox, with a fresh limit
        assert _inner(env).worker.cgroup.path != cgroup
    finally:
        env.close()
        loaded.unregister()
    assert not os.path.exists(cgroup), "the sandbox's memory cgroup outlived it"


def test_a_memory_limit_that_cannot_be_enforced_is_refused(hostile, monkeypatch):
    """On a machine where no memory cgroup can be made (played here: this process is told so), a limit the caller
    asked for is refused; the default limit then runs per process, and a warning says so."""
    monkeypatch.setattr(sandbox_module, "_HOME", "no memory cgroup here (played by the test)", raising=False)
    monkeypatch.setattr(sandbox_module, "_SUPPORT", None)
    monkeypatch.setattr(sandbox_module, "_WARNED_MEMORY", False, raising=False)
    with pytest.raises(errors.SandboxUnavailableError, match="memory cgroup") as info:
        load_env(hostile, trust_remote_code=True, sandbox=True, check=False, sandbox_limits={"memory_mb": 512})
    assert "played by the test" in str(info.value) and "memory_mb" in str(info.value)
    with pytest.warns(errors.HubEnvsWarning, match="covers each of its processes on its own"):
        loaded = load_env(hostile, trust_remote_code=True, sandbox=True, check=False)
    env = loaded.make()
    try:
        assert _inner(env).worker.cgroup is None
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()
        loaded.unregister()


# --- issue 30, Low: what a sandboxed env prints reaches the terminal escaped -------------------------------


def test_an_envs_exception_and_stderr_reach_the_terminal_escaped(hostile):
    loaded = load_env(hostile, trust_remote_code=True, sandbox=True, check=False, restart=True)
    env = loaded.make()
    try:
        env.reset(seed=0, options={"mode": "ansi"})
        with pytest.raises(ValueError) as info:
            env.step(env.action_space.sample())
        shown = [str(info.value), info.value.remote_traceback, str(info.value.__cause__)]
        assert not [s for s in shown if "\x1b" in s or "\x07" in s], shown
        assert "\\x1b[2Jthe env raised this" in str(info.value)  # escaped, still readable
        env.reset(seed=0, options={"mode": "ansi", "arg": "exit"})
        with pytest.raises(errors.EnvCrashedError) as info:
            env.step(env.action_space.sample())
        assert "\x1b" not in str(info.value) and "\x07" not in str(info.value)
        assert "\\x1b[31mred stderr" in str(info.value)  # the stderr tail, escaped
    finally:
        env.close()
        loaded.unregister()


def test_the_sandboxed_worker_keeps_its_private_tmp_writable_and_the_rest_read_only(hostile):
    """The new root holds the system folders read-only, a private /tmp, and nothing of the host's other folders."""
    loaded = load_env(hostile, trust_remote_code=True, sandbox=True, check=False)
    env = loaded.make()
    try:
        top = set(_probe(env, "listdir", "/"))
        assert {"usr", "etc", "tmp", "proc"} <= top and not top & {"srv", "mnt", "media", "var"}, top
        assert _probe(env, "write", "/tmp/scratch.txt") == "written"
        for path in ("/usr/pwned", "/etc/pwned", "/pwned", sys.prefix + "/pwned"):
            assert _probe(env, "write", path).startswith("refused"), path
    finally:
        env.close()
        loaded.unregister()
