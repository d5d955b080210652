"""Helpers for tests: copy env folders with edits, and re-publish a repo with hand-made changes.

``republish`` plays a careless (or malicious) publisher: it edits files of a published repo and
fixes up the manifest's hashes so integrity passes, the way only a hand-made repo could.
"""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

from huggingface_hub import HfApi, snapshot_download

from hub_envs.repo.format import MANIFEST_FILE, content_digest, hash_files, list_files

FIXTURES = Path(__file__).parent / "fixtures"
TINY = FIXTURES / "tiny_env"


def copy_env(
    tmp_path: Path, src: Path = TINY, name: str | None = None, edits: dict[str, Callable[[str], str]] | None = None
) -> Path:
    """A copy of an env folder, each ``edits[file](text)`` applied."""
    dest = tmp_path / (name or src.name)
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("__pycache__"))
    for rel, edit in (edits or {}).items():
        p = dest / rel
        p.write_text(edit(p.read_text()))
    return dest


def republish(
    api: HfApi, repo_id: str, edit: Callable[[Path], None], *, fix_hashes: bool = True, message: str = "hand edit"
) -> str:
    """Download main, apply ``edit(folder)``, (re)compute the manifest's hashes, upload as one commit."""
    src = Path(snapshot_download(repo_id, endpoint=api.endpoint, token=api.token))
    work = Path(str(src) + "-edit")
    if work.exists():
        shutil.rmtree(work)
    shutil.copytree(src, work, symlinks=False)
    edit(work)
    if fix_hashes:
        manifest = json.loads((work / MANIFEST_FILE).read_text())
        files = hash_files(work, list_files(work, skip=(MANIFEST_FILE,)))
        manifest["files"] = files
        manifest["content_digest"] = content_digest(files)
        (work / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*commit a data file.*")
        info = api.upload_folder(repo_id=repo_id, folder_path=str(work), commit_message=message, delete_patterns=["*"])
    shutil.rmtree(work)
    return info.oid


def saved_figures(monkeypatch, module) -> list:
    """The matplotlib figures ``module`` saves as report PNGs from now on (its ``save_figure``, still called: the
    PNGs are written as always), to assert on what the plot draws rather than on pixels."""
    figures, save = [], module.save_figure

    def spy(fig, path, **kw):
        figures.append(fig)
        return save(fig, path, **kw)

    monkeypatch.setattr(module, "save_figure", spy)
    return figures


def comparable_report(report) -> dict:
    """A reproduction report as a dict, minus what differs between identical runs (wall-clock times, settings)."""
    d = report.to_dict()
    d["provenance"].pop("generated_at")
    d["replay"].pop("seconds")
    for b in d["benchmarks"]:
        b.pop("seconds")
    d.pop("settings")
    d.pop("timings")
    return d


def build_wheel(out: Path, name: str, version: str, files: dict[str, str], requires: tuple[str, ...] = ()) -> Path:
    """A real wheel (PEP 427) of a pure-Python distribution ``name`` ``version`` holding ``files`` (path -> text),
    with ``Requires-Dist`` lines ``requires``: what pip or uv install like any other (no build backend needed)."""
    import base64
    import hashlib
    import zipfile

    dist = re.sub(r"[-_.]+", "_", name)
    info = f"{dist}-{version}.dist-info"
    members = dict(files)
    members[f"{info}/METADATA"] = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n" + "".join(
        f"Requires-Dist: {r}\n" for r in requires
    )
    members[f"{info}/WHEEL"] = "Wheel-Version: 1.0\nGenerator: hub-envs-tests\nRoot-Is-Purelib: true\nTag: py3-none-any\n"
    record = []
    for path, text in members.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(text.encode()).digest()).rstrip(b"=").decode()
        record.append(f"{path},sha256={digest},{len(text.encode())}")
    members[f"{info}/RECORD"] = "\n".join([*record, f"{info}/RECORD,,"]) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    wheel = out / f"{dist}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as zf:
        for path, text in members.items():
            zf.writestr(path, text)
    return wheel


def install_wheels(wheels: Path, target: Path, *requirements: str) -> Path:
    """``pip install --target`` of ``requirements`` from the folder of wheels ``wheels`` only (no index): a site
    folder to put on ``sys.path`` / ``PYTHONPATH``, as a user's own install of those versions."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-index"]
        + ["--find-links", str(wheels), "--target", str(target), *requirements],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return target


RAY = shutil.which("ray", path=str(Path(sys.executable).parent))  # this venv's `ray` command


def ray_installed() -> bool:
    """Ray importable in this Python and its ``ray`` command beside it (what the tests that run ``ray start`` need)."""
    try:
        return importlib.util.find_spec("ray") is not None and RAY is not None
    except (ImportError, ValueError):  # (a blocked import: sys.modules["ray"] = None)
        return False
