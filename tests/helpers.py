"""Helpers for tests: copy env folders with edits, and re-publish a repo with hand-made changes.

``republish`` plays a careless (or malicious) publisher: it edits files of a published repo and
fixes up the manifest's hashes so integrity passes, the way only a hand-made repo could.
"""

from __future__ import annotations

import json
import shutil
import warnings
from collections.abc import Callable
from pathlib import Path

from huggingface_hub import HfApi, snapshot_download

from hub_envs.repo_format import MANIFEST_FILE, content_digest, hash_files, list_files

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
