"""The package as users install it: a wheel built with ``pip wheel .`` carries every file hub-envs reads at run time
(the card template, the env entry template, the web page's templates and static files), and, installed on its own
(not this checkout, not the editable install), serves a Hub and pushes an env with its card."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import textwrap
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _tracked(*paths: str) -> list[str]:
    return subprocess.run(["git", "ls-files", *paths], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """A wheel built with ``pip wheel .`` from a clean copy of the tracked files (the checkout's own ``build/``
    would otherwise leak files git no longer has into it)."""
    src, out = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("wheel")
    for rel in _tracked("pyproject.toml", "README.md", "hub_envs"):
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, src / rel)
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "--quiet", "--disable-pip-version-check", "-w", str(out)],
        cwd=src,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    (built,) = out.glob("hub_envs-*.whl")
    return built


def test_the_wheel_carries_every_file_the_package_reads(wheel):
    names = {n for n in zipfile.ZipFile(wheel).namelist() if ".dist-info/" not in n}
    tracked = set(_tracked("hub_envs"))
    # every tracked file of the package is in the wheel (the lerobot plugin and templates included)...
    missing = sorted(tracked - names)
    assert not missing, f"the wheel lacks {missing}: list them in pyproject.toml's package-data"
    # ...and nothing else: no file git does not track, nothing of tests, example envs, docs
    assert names == tracked, sorted(names - tracked)


def test_the_installed_wheel_serves_a_hub_and_pushes_an_env_with_its_card(wheel, tmp_path):
    site = tmp_path / "site"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--no-deps",
            "--quiet",
            "--disable-pip-version-check",
            "--target",
            str(site),
            str(wheel),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    script = textwrap.dedent(
        f"""
        import hub_envs, huggingface_hub
        from pathlib import Path
        assert Path(hub_envs.__file__).is_relative_to({str(site)!r}), hub_envs.__file__  # the wheel, not the checkout
        from hub_envs.testing import HubServer, hub_environment
        from hub_envs import push_env
        with HubServer({str(tmp_path / "store")!r}) as server, hub_environment(server.endpoint, {str(tmp_path / "hf")!r}):
            result = push_env({str(ROOT / "envs" / "pendulum")!r}, "alice/pendulum", episodes=2, progress=False)
            card = Path(huggingface_hub.hf_hub_download("alice/pendulum", "README.md", revision=result.sha)).read_text()
            page = huggingface_hub.get_session().get(server.endpoint + "/alice/pendulum").text
            print("CARD", all(h in card for h in ("## Load it", "## Dataset", "## Benchmark results", "alice/pendulum")))
            print("PAGE", "hub.css" in page)
        """
    )
    env = {**os.environ, "PYTHONPATH": str(site), "HF_HUB_DISABLE_TELEMETRY": "1", "HF_HUB_DISABLE_XET": "1"}
    ran = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert ran.returncode == 0, ran.stdout[-3000:] + ran.stderr[-3000:]
    assert "CARD True" in ran.stdout and "PAGE True" in ran.stdout, ran.stdout


def test_the_architecture_map_names_every_module():
    """docs/architecture.md is the map of the package: a module it does not name is a module nobody finds.
    A top-level module is named as ``name.py``; a subpackage's modules by name in that subpackage's entry."""
    section = (ROOT / "docs" / "architecture.md").read_text()
    tree = section[section.index("```") + 3 : section.index("```", section.index("```") + 3)]
    entries: dict[str, str] = {}  # subpackage -> its lines in the map
    for line in tree.splitlines():
        head = re.match(r"  (\w+)/", line)
        if head:
            current = head.group(1)
        elif not line.startswith("   "):
            current = None
        if line.startswith("  ") and current:
            entries[current] = entries.get(current, "") + line + "\n"
    missing = []
    for path in sorted((ROOT / "hub_envs").rglob("*.py")):
        rel = path.relative_to(ROOT / "hub_envs")
        if path.stem == "__init__" or rel.parts[0] == "templates":
            continue
        if len(rel.parts) == 1:
            found = re.search(rf"(?<![\w.]){re.escape(path.name)}\b", tree)
        else:
            # an item of the entry's list: after ": ", ", " or a line's indent; before ",", " (" or the line's end
            item = rf"(?:[:,]\s+|^\s+){re.escape(path.stem)}(?=,|\s+\(|\s*$)"
            found = re.search(item, entries.get(rel.parts[0], ""), re.MULTILINE)
        if not found:
            missing.append(str(rel))
    assert not missing, f"docs/architecture.md does not name {missing}"


def test_the_architecture_layers_are_the_layers_lint_imports_enforces():
    """docs/architecture.md's list of layers is the layers contract of pyproject.toml's [tool.importlinter] (what `make lint` runs):
    the map a newcomer reads is the architecture the tool checks, not a description that can drift from it."""
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c["layers"] for c in contracts if c["type"] == "layers")
    expected = [" | ".join(part.strip().removeprefix("hub_envs.") for part in layer.split("|")) for layer in layers]
    section = (ROOT / "docs" / "architecture.md").read_text()
    block = section[section.index("The layers, top to bottom") :]
    block = block[block.index("```") + 3 : block.index("```", block.index("```") + 3)]
    assert [line.strip() for line in block.strip().splitlines()] == expected
