"""A hostile env repo (or a hostile file next to one) against the real public API.

Each test reproduces one red-team finding: a publisher (``helpers.republish``: edit files, fix up the
manifest's hashes so integrity passes) or a cloned template or a writable cache folder attacks
``push_env`` / ``load_env`` / ``reproduce`` / ``env_from_dataset`` on the real loopback Hub. Where code
would run, the payload writes a marker file, so "nothing ran" is a fact the test checks.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import marshal
import os
import py_compile
import shutil
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import pytest
from helpers import TINY, copy_env, republish

from hub_envs import env_from_dataset, errors, load_env, push_env, reproduce
from hub_envs.dataset.reader import dataset_fingerprint, read_info
from hub_envs.paths import hub_envs_home
from hub_envs.repo.format import MANIFEST_FILE, Manifest, check_names_belong_to, content_digest, hash_files, list_files, safe_text

PAYLOAD = "import os, pathlib\npathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('pwned')\n"


@pytest.fixture
def marker(tmp_path, monkeypatch) -> Path:
    path = tmp_path / "pwned-marker"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(path))
    return path


def _push(folder: Path, repo_id: str, **kw):
    return push_env(folder, repo_id, **{"episodes": 1, "progress": False, **kw})


def _relist(folder: Path, extra: list[str] = ()) -> None:
    """What a malicious publisher does by hand: list every file (and ``extra``, which ``list_files`` skips)."""
    manifest = json.loads((folder / MANIFEST_FILE).read_text())
    manifest["files"] = hash_files(folder, list_files(folder, skip=(MANIFEST_FILE,)) + list(extra))
    manifest["content_digest"] = content_digest(manifest["files"])
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")


def _edit_manifest(folder: Path, fn) -> None:
    manifest = json.loads((folder / MANIFEST_FILE).read_text())
    fn(manifest)
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")


def _edit_info(folder: Path, fn) -> None:
    path = folder / "dataset" / "meta" / "info.json"
    info = json.loads(path.read_text())
    fn(info)
    path.write_text(json.dumps(info, indent=4))


def _plant_pyc(source_py: Path, evil_source: str, scratch: Path) -> Path:
    """An unchecked-hash ``__pycache__`` entry for ``source_py`` that runs ``evil_source`` instead of it."""
    evil = scratch / f"evil-{source_py.stem}.py"
    evil.write_text(evil_source)
    cfile = Path(importlib.util.cache_from_source(str(source_py)))
    py_compile.compile(str(evil), cfile=str(cfile), invalidation_mode=py_compile.PycInvalidationMode.UNCHECKED_HASH)
    return cfile


# --- 1. bytecode outside the folders the source-only finder covered ---------------------------------


def _import_helper_from(folder: Path, sub: str = "dataset") -> None:
    """tiny.py gains a harmless-looking import of ``<sub>/helper.py`` (``VALUE = 1``)."""
    (folder / sub / "helper.py").write_text("VALUE = 1\n")
    tiny = folder / "tiny.py"
    tiny.write_text(f"from .{sub} import helper as _calibration\n" + tiny.read_text())


def test_bytecode_listed_in_a_manifest_is_refused_before_anything_runs(hub, tmp_path, marker):
    """The manifest lists an unchecked-hash ``dataset/__pycache__/helper.*.pyc`` beside the helper.py that
    tiny.py imports. (The loopback server refuses to store bytecode in an env repo, the real Hub does
    not: here the manifest lists it and the file stays out; the next test runs the full attack.)"""
    _push(TINY, "mallory/pyc-dataset")
    pyc = Path(importlib.util.cache_from_source("dataset/helper.py")).as_posix()

    def plant(folder: Path) -> None:
        _import_helper_from(folder)
        _relist(folder)
        _edit_manifest(folder, lambda m: m["files"].__setitem__(pyc, "0" * 64))

    sha = republish(hub.api, "mallory/pyc-dataset", plant, fix_hashes=False)
    with pytest.raises(errors.ManifestError) as info:
        load_env(f"mallory/pyc-dataset@{sha}", trust_remote_code=True)
    message = str(info.value)
    assert "mallory/pyc-dataset@" in message and f"'{pyc}'" in message
    assert "compiled bytecode" in message and "re-publish with push_env" in message
    assert not marker.exists()

    # LeRobot's own loader (env.py, which needs no hub-envs) refuses such a manifest too
    from lerobot.envs.factory import make_env

    with pytest.raises(RuntimeError, match="compiled bytecode"):
        make_env(f"mallory/pyc-dataset@{sha}", n_envs=1, trust_remote_code=True)
    assert not marker.exists()


def test_bytecode_under_dataset_in_a_checkout_of_a_published_repo_never_runs(hub, tmp_path, marker):
    """The full attack, on a published repo checked out locally (from a Hub that stores bytecode):
    integrity passes (the .pyc is listed), the trust prompt shows only .py files, and Python's default
    finder for dataset/ would run the .pyc instead of the helper.py a reviewer reads."""
    from huggingface_hub import snapshot_download

    result = _push(TINY, "mallory/pyc-checkout")
    checkout = tmp_path / "checkout"
    shutil.copytree(snapshot_download("mallory/pyc-checkout", revision=result.sha, cache_dir=tmp_path / "dl"), checkout)
    _import_helper_from(checkout)
    cfile = _plant_pyc(checkout / "dataset" / "helper.py", PAYLOAD + "VALUE = 1\n", tmp_path)
    _relist(checkout, extra=[cfile.relative_to(checkout).as_posix()])

    with pytest.raises(errors.ManifestError) as info:
        load_env(checkout)
    assert cfile.relative_to(checkout).as_posix() in str(info.value) and "compiled bytecode" in str(info.value)
    assert not marker.exists()


_EXTENSION_C = r"""
#include <Python.h>
#include <stdio.h>
#include <stdlib.h>
static struct PyModuleDef helper_module = {PyModuleDef_HEAD_INIT, "helper", NULL, -1, NULL};
PyMODINIT_FUNC PyInit_helper(void) {
    const char *marker = getenv("HUB_ENVS_TEST_MARKER");
    if (marker) { FILE *f = fopen(marker, "w"); if (f) { fputs("pwned", f); fclose(f); } }
    PyObject *m = PyModule_Create(&helper_module);
    if (m) PyModule_AddIntConstant(m, "VALUE", 2);
    return m;
}
"""


@pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler to build the planted extension module")
def test_an_extension_module_under_dataset_is_never_imported(hub, tmp_path, marker):
    """A listed ``dataset/helper.<EXT_SUFFIX>`` (the loopback server stores it) beside the helper.py that
    tiny.py imports: Python's default finder prefers the extension module; hub-envs imports sources only,
    from every folder of the repo."""
    import sysconfig

    _push(TINY, "mallory/so-dataset")
    source = tmp_path / "helper.c"
    source.write_text(_EXTENSION_C)
    built = tmp_path / f"helper{sysconfig.get_config_var('EXT_SUFFIX')}"
    subprocess.run(
        ["cc", "-shared", "-fPIC", f"-I{sysconfig.get_paths()['include']}", str(source), "-o", str(built)],
        check=True,
        capture_output=True,
        timeout=120,
    )

    def plant(folder: Path) -> None:
        _import_helper_from(folder)
        shutil.copy(built, folder / "dataset" / built.name)

    sha = republish(hub.api, "mallory/so-dataset", plant)
    assert f"dataset/{built.name}" in hub.api.list_repo_files("mallory/so-dataset", revision=sha)
    loaded = load_env(f"mallory/so-dataset@{sha}", trust_remote_code=True)
    try:
        assert sys.modules[f"{loaded.env_class.__module__.rsplit('.', 1)[0]}.dataset.helper"].VALUE == 1
        assert not marker.exists()
    finally:
        loaded.unregister()


@pytest.mark.parametrize("sub", ["dataset", "media", "assets/deep", "dataset/nested"])
def test_every_folder_of_env_code_imports_its_sources_only(tmp_path, marker, sub):
    """The finder layer on its own (what runs if a .pyc ever got past the manifest): a package folder
    anywhere below the env's code, dataset/ and media/ included, never has its __pycache__ read."""
    from hub_envs.envcode.importing import forget_env_folder, import_env_folder

    folder = copy_env(tmp_path, name="env-with-sub")
    (folder / sub).mkdir(parents=True)
    (folder / sub / "helper.py").write_text("VALUE = 'source'\n")
    _plant_pyc(folder / sub / "helper.py", PAYLOAD + "VALUE = 'bytecode'\n", tmp_path)
    key = f"adversarial-finder-{sub.replace('/', '-')}"
    pkg = import_env_folder(folder, key)
    try:
        module = importlib.import_module(f"{pkg.__name__}.{sub.replace('/', '.')}.helper")
        assert module.VALUE == "source"
        assert not marker.exists()
    finally:
        forget_env_folder(key)


def test_push_refuses_compiled_files_and_never_publishes_pycache(hub, tmp_path):
    folder = copy_env(tmp_path, name="compiled")
    (folder / "fast.cpython-313-x86_64-linux-gnu.so").write_bytes(b"\x7fELF not really")
    py_compile.compile(str(folder / "dynamics.py"), cfile=str(folder / "legacy.pyc"))
    with pytest.raises(errors.EnvFolderError) as info:
        _push(folder, "mallory/compiled")
    message = str(info.value)
    assert "fast.cpython-313-x86_64-linux-gnu.so" in message and "legacy.pyc" in message
    assert "Delete them" in message and ".py sources only" in message
    assert not hub.api.repo_exists("mallory/compiled")

    # what the author's own Python writes (__pycache__/) is skipped, never published nor listed
    (folder / "fast.cpython-313-x86_64-linux-gnu.so").unlink()
    (folder / "legacy.pyc").unlink()
    py_compile.compile(str(folder / "dynamics.py"))
    assert any((folder / "__pycache__").iterdir())
    result = _push(folder, "mallory/compiled")
    assert not [p for p in result.manifest.files if "__pycache__" in p or p.endswith((".pyc", ".pyo"))]
    assert not [p for p in hub.api.list_repo_files("mallory/compiled", revision=result.sha) if "__pycache__" in p]


# --- 2. symlinks out of the env folder --------------------------------------------------------------


def test_push_refuses_a_symlink_out_of_the_env_folder(hub, tmp_path):
    secret = tmp_path / "home" / ".ssh" / "id_ed25519"
    secret.parent.mkdir(parents=True)
    secret.write_text("-----BEGIN OPENSSH PRIVATE KEY-----\nnot-for-the-hub\n-----END OPENSSH PRIVATE KEY-----\n")
    folder = copy_env(tmp_path, name="cloned-template")
    (folder / "assets").mkdir()
    (folder / "assets" / "calibration.yaml").symlink_to(secret)

    with pytest.raises(errors.EnvFolderError) as info:
        _push(folder, "mallory/leak")
    message = str(info.value)
    assert "assets/calibration.yaml" in message and os.path.realpath(secret) in message
    assert "copy it into the folder" in message and "remove the link" in message
    assert not hub.api.repo_exists("mallory/leak")

    # a dangling link and a linked folder outside are refused the same way
    (folder / "assets" / "calibration.yaml").unlink()
    (folder / "assets" / "calibration.yaml").symlink_to(tmp_path / "no-such-file")
    (folder / "keys").symlink_to(secret.parent, target_is_directory=True)
    with pytest.raises(errors.EnvFolderError) as info:
        _push(folder, "mallory/leak")
    assert "assets/calibration.yaml -> " in str(info.value) and "(the target does not exist)" in str(info.value)
    assert f"keys -> {os.path.realpath(secret.parent)} (outside the env folder" in str(info.value)
    assert not hub.api.repo_exists("mallory/leak")

    # a link to a file inside the folder is fine: its target's contents are published
    (folder / "keys").unlink()
    (folder / "assets" / "calibration.yaml").unlink()
    (folder / "assets" / "real.yaml").write_text("gain: 1.0\n")
    (folder / "assets" / "calibration.yaml").symlink_to("real.yaml")
    result = _push(folder, "mallory/leak")
    local = hub.api.hf_hub_download("mallory/leak", "assets/calibration.yaml", revision=result.sha, cache_dir=tmp_path / "dl")
    assert Path(local).read_text() == "gain: 1.0\n"


# --- 3. the dataset's data_path ---------------------------------------------------------------------


def test_a_data_path_outside_the_verified_snapshot_is_refused(hub, tmp_path, marker):
    """The dataset's parquet moved outside the snapshot (beside the HF cache), data_path pointing there
    with '../': replay would read a file nobody verified and still say 'reproduce exactly'."""
    _push(TINY, "mallory/data-path", episodes=2)
    outside = hub.hf_home.parent / "outside"

    def escape(folder: Path) -> None:
        data = folder / "dataset" / "data" / "chunk-000" / "file-000.parquet"
        (outside / "chunk-000").mkdir(parents=True)
        shutil.copy(data, outside / "chunk-000" / "file-000.parquet")
        data.unlink()
        # dataset/ -> <sha> -> snapshots -> models--mallory--data-path -> hub -> hf_home -> their parent
        _edit_info(
            folder,
            lambda i: i.__setitem__(
                "data_path", "../../../../../../outside/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
            ),
        )
        _edit_manifest(folder, lambda m: m["dataset"].__setitem__("fingerprint", dataset_fingerprint(folder / "dataset")))

    sha = republish(hub.api, "mallory/data-path", escape)
    with pytest.raises(errors.DatasetError) as info:
        reproduce(f"mallory/data-path@{sha}", trust_remote_code=True, workers=1, progress=False, write=False)
    message = str(info.value)
    assert "data_path" in message and "info.json" in message and "outside the dataset folder" in message
    assert "re-publish" in message


@pytest.mark.parametrize(
    "key, template, says",
    [
        ("data_path", "data/chunk-{chunk_index.__class__}/file-{file_index:03d}.parquet", "{chunk_index.__class__}"),
        ("data_path", "data/chunk-{chunk_index:03d}/file-{file_index[0]}.parquet", "{file_index[0]}"),
        ("data_path", "data/{chunk_index!r}/file-{file_index:03d}.parquet", "{chunk_index!r}"),
        ("data_path", "data/{episode_chunk:03d}/file-{file_index:03d}.parquet", "{episode_chunk}"),
        ("data_path", "data/chunk-{chunk_index:>30}/file-{file_index:03d}.parquet", "not an integer format"),
        ("data_path", "/etc/{chunk_index}{file_index}", "outside the dataset folder"),
        ("data_path", 5, "must be a non-empty path template string"),
        ("video_path", "../videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4", "outside the dataset folder"),
        ("video_path", "videos/{video_key.__init__.__globals__}/x.mp4", "{video_key.__init__.__globals__}"),
    ],
)
def test_a_data_path_template_is_named_integer_fields_inside_the_dataset(tmp_path, key, template, says):
    root = tmp_path / "ds"
    (root / "meta").mkdir(parents=True)
    (root / "meta" / "info.json").write_text(json.dumps({"codebase_version": "v3.0", "features": {}, key: template}))
    with pytest.raises(errors.DatasetError) as info:
        read_info(root)
    message = str(info.value)
    assert key in message and "info.json" in message and says in message and "re-publish" in message


def test_a_lerobot_style_data_path_is_accepted(tmp_path):
    root = tmp_path / "ds"
    (root / "meta").mkdir(parents=True)
    info = {
        "codebase_version": "v3.0",
        "features": {},
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
    }
    (root / "meta" / "info.json").write_text(json.dumps(info))
    assert read_info(root)["data_path"] == info["data_path"]


# --- 4. the bytecode cache under HUB_ENVS_HOME ------------------------------------------------------


def test_a_planted_bytecode_cache_entry_never_runs(hub, tmp_path, marker):
    """Anyone who can write ``$HUB_ENVS_HOME/bytecode`` planted code objects under the keys hub-envs used
    (sha256 of magic number, optimization level, path and source): a later load in a fresh process ran them."""
    result = _push(TINY, "mallory/bytecode")
    loaded = load_env(f"mallory/bytecode@{result.sha}", trust_remote_code=True)
    folder = Path(loaded.path).resolve()
    loaded.unregister()
    cache = hub_envs_home() / "bytecode"
    assert not cache.exists() or not any(cache.iterdir()), "hub-envs writes no bytecode cache"
    cache.mkdir(parents=True, exist_ok=True)
    for py in sorted(folder.glob("*.py")):
        source, path = py.read_bytes(), str(py)
        key = hashlib.sha256(
            b"\0".join(
                [importlib.util.MAGIC_NUMBER, str(sys.flags.optimize).encode(), path.encode("utf-8", "surrogateescape"), source]
            )
        ).hexdigest()
        (cache / f"{key}.bin").write_bytes(marshal.dumps(compile(source + b"\n" + PAYLOAD.encode(), path, "exec")))

    code = (
        "import sys; from hub_envs import load_env; loaded = load_env(sys.argv[1], trust_remote_code=True); print(loaded.gym_id)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, f"mallory/bytecode@{result.sha}"],
        env=dict(os.environ),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip().startswith("mallory/bytecode-")
    assert not marker.exists()


# --- 5. a malformed check-cache entry --------------------------------------------------------------


@pytest.mark.parametrize(
    "how",
    ["no-features", "rows-not-list", "row-unknown-field", "not-an-object", "truncated", "failing-report", "nested-too-deep"],
)
def test_a_malformed_check_cache_entry_is_recomputed_never_a_pass(hub, tmp_path, how):
    result = _push(TINY, f"mallory/check-cache-{how}")
    ref = f"mallory/check-cache-{how}@{result.sha}"
    load_env(ref, trust_remote_code=True).unregister()
    entries = sorted((hub_envs_home() / "checks").glob("*.json"))
    assert len(entries) == 1
    entry = json.loads(entries[0].read_text())
    second = load_env(ref, trust_remote_code=True)
    assert "cached" in second.report.fingerprint  # a good entry is reused
    second.unregister()

    if how == "no-features":
        entry.pop("features")
    elif how == "rows-not-list":
        entry["features"]["rows"] = "nope"
    elif how == "row-unknown-field":
        entry["features"]["rows"][0]["surprise"] = 1
    elif how == "failing-report":  # hand-edited: says the checks ran and failed, or anything else
        entry["features"]["ok"] = False
        entry["features"]["rows"][0]["problems"] = ["live shape (3,) != declared (2,)"]
    if how == "not-an-object":
        text = json.dumps([entry])
    elif how == "truncated":
        text = json.dumps(entry)[:-20]
    elif how == "nested-too-deep":
        text = json.dumps({**entry, "features": None})[:-1] + ', "x": ' + "[" * 200_000 + "]" * 200_000 + "}"
    else:
        text = json.dumps(entry)
    entries[0].write_text(text)

    loaded = load_env(ref, trust_remote_code=True)  # neither a crash nor a verdict taken from the entry
    assert "cached" not in loaded.report.fingerprint
    assert loaded.report.features is not None and loaded.report.features.ok
    loaded.unregister()
    again = load_env(ref, trust_remote_code=True)  # the entry was rewritten, and is good again
    assert "cached" in again.report.fingerprint
    again.unregister()


# --- 6. terminal escapes in repo-controlled names ---------------------------------------------------

UNSAFE = ("\x1b", "\x9b", "\u202e", "\x07")


def _assert_terminal_safe(message: str) -> None:
    assert not any(ch in message for ch in UNSAFE), repr(message)


@pytest.mark.parametrize(
    "name, shown",
    [
        ("assets/\x9b2J\u202etxt.py.yaml", "assets/\\x9b2J\\u202etxt.py.yaml"),  # C1 CSI (8-bit terminals) and a bidi override
        ("x\x1b]0;owned\x07.py", "x\\x1b]0;owned\\x07.py"),  # C0 ESC ... BEL: sets the terminal's title
    ],
)
def test_escape_sequences_in_listed_file_names_are_refused_and_shown_escaped(hub, tmp_path, name, shown):
    """The manifest lists a file whose name holds terminal control sequences. (The name is only written
    into the manifest: the loopback server refuses to store such file names, which a manifest need not.)"""
    repo = f"mallory/escapes-{len(name)}"
    _push(TINY, repo)
    sha = republish(
        hub.api, repo, lambda f: _edit_manifest(f, lambda m: m["files"].__setitem__(name, "0" * 64)), fix_hashes=False
    )
    with pytest.raises(errors.ManifestError) as info:
        load_env(f"{repo}@{sha}", trust_remote_code=True)
    message = str(info.value)
    _assert_terminal_safe(message)
    assert shown in message and "control or bidirectional-override" in message and "re-publish" in message


def test_an_unlisted_file_with_escapes_in_its_name_is_reported_escaped(hub, tmp_path):
    """An unlisted code file named with an ESC sequence and a bidi override, in a checkout of a published
    repo (a local file system, or a Hub, may hold such names): the IntegrityError shows it escaped."""
    from huggingface_hub import snapshot_download

    result = _push(TINY, "mallory/escapes-unlisted")
    checkout = tmp_path / "checkout"
    shutil.copytree(snapshot_download("mallory/escapes-unlisted", revision=result.sha, cache_dir=tmp_path / "dl"), checkout)
    (checkout / "readme\x1b[2J\u202eyp.py").write_text("x = 1\n")
    with pytest.raises(errors.IntegrityError) as info:
        load_env(checkout)
    message = str(info.value)
    _assert_terminal_safe(message)
    assert "unlisted  readme\\x1b[2J\\u202eyp.py" in message


def test_a_listed_name_longer_than_file_systems_allow_is_refused(hub, tmp_path):
    _push(TINY, "mallory/long-name")
    long = "assets/" + "a" * 300 + ".txt"
    sha = republish(
        hub.api,
        "mallory/long-name",
        lambda f: _edit_manifest(f, lambda m: m["files"].__setitem__(long, "0" * 64)),
        fix_hashes=False,
    )
    with pytest.raises(errors.ManifestError, match=r"longer than 255 bytes.*Shorten"):
        load_env(f"mallory/long-name@{sha}", trust_remote_code=True)


def test_lerobots_loader_tells_a_bad_publication_from_a_bad_download(hub, tmp_path):
    """env.py (LeRobot's own path) refuses a code file whose hash is not the manifest's. When the cached file is
    byte for byte what the Hub serves, the publication is at fault and re-downloading cannot help: it says so;
    when the cache was damaged after the download, it says to download again."""
    from huggingface_hub import snapshot_download
    from lerobot.envs.factory import make_env as lerobot_make_env

    from hub_envs.testing import hub_environment

    _push(TINY, "mallory/bad-publication")
    sha = republish(hub.api, "mallory/bad-publication", lambda f: (f / "dynamics.py").write_text("GAIN = 9\n"), fix_hashes=False)
    with hub_environment(hub.endpoint, tmp_path / "fresh"):
        with pytest.raises(RuntimeError, match=r"dynamics\.py are exactly what the Hub serves.*will not help.*re-publish"):
            lerobot_make_env(f"mallory/bad-publication@{sha}", n_envs=1, trust_remote_code=True)
    _push(TINY, "mallory/bad-cache")
    sha = hub.api.model_info("mallory/bad-cache").sha
    with hub_environment(hub.endpoint, tmp_path / "fresh2"):
        snapshot = Path(snapshot_download("mallory/bad-cache", revision=sha))
        blob = (snapshot / "dynamics.py").resolve()
        blob.write_text(blob.read_text() + "\n# damaged on disk\n")  # the cache changed after the download
        with pytest.raises(RuntimeError, match=r"Delete this snapshot from the cache and download it again"):
            lerobot_make_env(f"mallory/bad-cache@{sha}", n_envs=1, trust_remote_code=True)


def test_safe_text_escapes_what_a_terminal_would_act_on():
    assert safe_text("tiny.py") == "tiny.py" and safe_text("a b") == "a b"
    assert safe_text("\x1b[2J\x9b\x07\u202e\u2066\u200f\x7f\udcff") == "\\x1b[2J\\x9b\\x07\\u202e\\u2066\\u200f\\x7f\\udcff"
    assert safe_text("a\nb\\x1b") == "a\\nb\\\\x1b"  # a literal backslash cannot pass for an escape
    assert safe_text("ação.py") == "ação.py"


# --- 7. a deeply nested info.json -------------------------------------------------------------------


def test_a_deeply_nested_dataset_info_is_a_dataset_error(hub, tmp_path, marker):
    _push(TINY, "mallory/deep-info")
    deep = '{"features": ' + "[" * 100_000 + "]" * 100_000 + ', "codebase_version": "v3.0"}'
    sha = republish(hub.api, "mallory/deep-info", lambda f: (f / "dataset" / "meta" / "info.json").write_text(deep))
    # before any trust: env_from_dataset reads the dataset's env_meta first
    with pytest.raises(errors.DatasetError) as info:
        env_from_dataset(f"mallory/deep-info@{sha}")
    assert "dataset/meta/info.json" in str(info.value) and "nested too deeply" in str(info.value)
    with pytest.raises(errors.DatasetError) as info:
        load_env(f"mallory/deep-info@{sha}", trust_remote_code=True)
    assert "mallory/deep-info@" in str(info.value) and "info.json" in str(info.value) and "push_env" in str(info.value)


# --- 8. names under another user's namespace --------------------------------------------------------


def test_a_manifest_registering_names_under_another_namespace_is_refused(hub, tmp_path):
    _push(TINY, "mallory/lookalike")
    before = set(gym.registry)

    def claim(folder: Path) -> None:
        _edit_manifest(folder, lambda m: m.update(gym_id="alice/pendulum", env_type="alice/pendulum"))

    sha = republish(hub.api, "mallory/lookalike", claim)
    with pytest.raises(errors.ManifestError) as info:
        load_env(f"mallory/lookalike@{sha}", trust_remote_code=True)
    message = str(info.value)
    assert "gym_id 'alice/pendulum'" in message and "'mallory/lookalike'" in message and "'mallory'" in message
    assert "re-publish with push_env" in message
    assert set(gym.registry) == before


def test_check_names_belong_to_compares_with_the_repo_actually_loaded(hub, tmp_path):
    result = _push(TINY, "mallory/spoof")
    sha = republish(
        hub.api,
        "mallory/spoof",
        lambda f: _edit_manifest(
            f, lambda m: m.update(repo_id="alice/pendulum", gym_id="alice/pendulum", env_type="alice/pendulum")
        ),
    )
    from huggingface_hub import snapshot_download

    manifest = Manifest.read(Path(snapshot_download("mallory/spoof", revision=sha, cache_dir=tmp_path / "dl")))
    with pytest.raises(errors.ManifestError) as info:
        check_names_belong_to(manifest, "mallory/spoof")
    assert "'alice/pendulum'" in str(info.value) and "'mallory/spoof'" in str(info.value)
    check_names_belong_to(result.manifest, "mallory/spoof")  # what push_env writes belongs to its repo
    check_names_belong_to(result.manifest, "Mallory/spoof")  # namespaces compare as the Hub does


def test_a_manifest_claiming_another_users_repo_id_too_is_refused_by_load_env(hub, tmp_path):
    _push(TINY, "mallory/spoof-all")
    sha = republish(
        hub.api,
        "mallory/spoof-all",
        lambda f: _edit_manifest(
            f, lambda m: m.update(repo_id="alice/pendulum", gym_id="alice/pendulum", env_type="alice/pendulum")
        ),
    )
    before = set(gym.registry)
    try:
        with pytest.raises(errors.ManifestError, match="alice/pendulum"):
            load_env(f"mallory/spoof-all@{sha}", trust_remote_code=True).unregister()
    finally:
        for name in set(gym.registry) - before:
            gym.registry.pop(name, None)


def test_an_edited_checker_never_reuses_the_cached_verdicts(tmp_path):
    """The check cache's key covers hub-envs' own sources: editing any module of the package (an editable install
    under development, a ``git checkout``) changes it, so verdicts reached by other checking code are not reused;
    an untouched tree keeps its key (the cache works)."""
    from hub_envs.loading import check_cache
    from hub_envs.paths import PACKAGE_DIR

    tree = tmp_path / "hub_envs"
    shutil.copytree(PACKAGE_DIR, tree, ignore=shutil.ignore_patterns("__pycache__"))
    before = check_cache._checker_source_digest(tree)
    assert check_cache._checker_source_digest(tree) == before
    (tree / "__pycache__").mkdir(exist_ok=True)
    (tree / "__pycache__" / "x.cpython-313.pyc").write_bytes(b"bytecode is not a source")
    assert check_cache._checker_source_digest(tree) == before
    target = tree / "harness" / "checks.py"
    text, stat = target.read_text(), target.stat()
    time.sleep(0.05)  # past the kernel's timestamp tick (a few ms), as any real edit after an install is
    target.write_text(text.replace("0", "1", 1))  # an edit that keeps the size, and the old mtime put back
    os.utime(target, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert target.stat().st_size == stat.st_size and target.stat().st_mtime_ns == stat.st_mtime_ns
    edited = check_cache._checker_source_digest(tree)
    assert edited != before
    (tree / "new_module.py").write_text("x = 1\n")  # a module added
    assert check_cache._checker_source_digest(tree) not in (before, edited)
