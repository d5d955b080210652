"""Git LFS in the loopback Hub server, through the unmodified huggingface_hub client (0.35 and 1.x).

That a file went through LFS is read from the server's log (``lfs: stored <sha256> ... via basic |
multipart``, one line per object it stored), never assumed. Raw requests stand in for what the
client would not send: wrong bytes, forged upload URLs, a commit naming an object never uploaded.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
from pathlib import Path

import pytest
import requests
from helpers import TINY
from huggingface_hub import CommitOperationAdd, HfApi, constants, hf_hub_download, snapshot_download

from hub_envs import _compat, load_env, push_env
from hub_envs.repo import hub_io
from hub_envs.testing import HubServer, add_random_data_files, hub_environment

MiB = 1024 * 1024
CHUNK_MB = 4  # the module's server sends files over 4 MiB through the multipart transfer


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _stored(server: HubServer) -> dict[str, str]:
    """sha256 -> transfer ("basic" / "multipart") of every object the server logged as stored via LFS."""
    return {m.group(1): m.group(2) for m in re.finditer(r"lfs: stored ([0-9a-f]{64}) .* via (\w+)", server.output())}


class Faults:
    def __init__(self, path: Path):
        self.path = path
        path.write_text("[]")

    def inject(self, *rules: dict) -> None:
        self.path.write_text(json.dumps(list(rules)))

    def heal(self) -> None:
        self.path.write_text("[]")


@pytest.fixture(scope="module")
def lfs_server(tmp_path_factory):
    root = tmp_path_factory.mktemp("lfs")
    faults = Faults(root / "faults.json")
    env = {"HUB_ENVS_SERVER_LFS_CHUNK_MB": str(CHUNK_MB), "HUB_ENVS_SERVER_FAULTS": str(faults.path)}
    with HubServer(root / "hub-data", env=env) as server:
        server.faults = faults
        yield server


@pytest.fixture
def lfs(lfs_server, tmp_path):
    with hub_environment(lfs_server.endpoint, tmp_path / "hf_home"):
        yield lfs_server


def test_large_and_parquet_files_go_through_lfs_and_come_back_bit_identical(lfs, tmp_path):
    api = HfApi(endpoint=lfs.endpoint)
    api.create_repo("lfs/mixed")
    big = os.urandom(11 * MiB + 123)  # over the Hub's 10 MB rule, and over the chunk size: multipart
    table = b"PAR1" + os.urandom(5000) + b"PAR1"  # *.parquet: an LFS pattern of the default .gitattributes
    text = b"# hello\n" * 10  # small text: regular, inline in the commit
    files = {"data/big.dat": big, "data/chunk-000/file-000.parquet": table, "README.md": text}
    sha = api.create_commit("lfs/mixed", [CommitOperationAdd(p, d) for p, d in files.items()], commit_message="m").oid

    stored = _stored(lfs)
    assert stored.get(_sha(big)) == "multipart" and stored.get(_sha(table)) == "basic"
    assert _sha(text) not in stored

    info = {f.path: f for f in api.get_paths_info("lfs/mixed", list(files), revision=sha)}
    assert info["data/big.dat"].lfs.sha256 == _sha(big) and info["data/big.dat"].lfs.size == len(big)
    assert info["data/big.dat"].lfs.pointer_size == len(
        f"version https://git-lfs.github.com/spec/v1\noid sha256:{_sha(big)}\nsize {len(big)}\n"
    )
    assert info["README.md"].lfs is None
    # the git id of an LFS file is its pointer's, as in git (so commit ids stay git's)
    assert info["data/big.dat"].blob_id != hashlib.sha1(b"blob %d\0" % len(big) + big).hexdigest()
    tree = {f.path: f for f in api.list_repo_tree("lfs/mixed", recursive=True, revision=sha) if hasattr(f, "lfs")}
    assert tree["data/chunk-000/file-000.parquet"].lfs.sha256 == _sha(table)

    url = f"{lfs.endpoint}/lfs/mixed/resolve/{sha}/data/big.dat"
    head = requests.head(url, timeout=10)
    assert head.headers["ETag"] == head.headers["X-Linked-Etag"] == f'"{_sha(big)}"'
    assert head.headers["X-Linked-Size"] == str(len(big))
    part = requests.get(url, headers={"Range": "bytes=1000-1999"}, timeout=10)
    assert part.status_code == 206 and part.content == big[1000:2000]

    for path, data in files.items():
        assert Path(hf_hub_download("lfs/mixed", path, revision=sha, cache_dir=tmp_path / "c")).read_bytes() == data

    # the same content again: nothing uploaded, no new commit (the client compares preupload's sha256)
    again = api.create_commit("lfs/mixed", [CommitOperationAdd(p, d) for p, d in files.items()], commit_message="again")
    assert again.oid == sha and lfs.output().count(f"lfs: stored {_sha(big)}") == 1


def test_an_env_repo_with_a_200_mib_dataset_goes_through_lfs_and_loads_back_bit_identical(lfs, tmp_path):
    # push_env's repo of the tiny env, its dataset grown by 4 data files of 50 MiB listed in the manifest, published
    # as push_env publishes (hub_io.publish_folder, one commit); a cold load fetches none of them, fetch_dataset()
    # fetches and verifies all of them
    small = push_env(TINY, "lfs/env", episodes=2, progress=False).sha
    folder = Path(snapshot_download("lfs/env", revision=small, local_dir=tmp_path / "repo"))
    shutil.rmtree(folder / ".cache", ignore_errors=True)
    digests = add_random_data_files(folder, 4, 50)
    big = hub_io.publish_folder(folder, "lfs/env", parent_commit=small, remote_files=[], message="a 200 MiB dataset")
    shutil.rmtree(folder)  # two test legs side by side: no more copies of 200 MiB than needed

    stored = _stored(lfs)
    assert all(stored.get(d) == "multipart" for d in digests.values()), stored  # through LFS, in parts

    with hub_environment(lfs.endpoint, tmp_path / "loader"):
        loaded = load_env(f"lfs/env@{big}", trust_remote_code=True)
        loaded.unregister()
        assert not any((loaded.path / rel).exists() for rel in digests)  # a cold load fetches no data file
        root = loaded.fetch_dataset()
        for rel, digest in digests.items():
            h = hashlib.sha256()
            with open(root.parent / rel, "rb") as f:
                while block := f.read(8 * MiB):
                    h.update(block)
            assert h.hexdigest() == digest
    shutil.rmtree(tmp_path / "loader")


def test_preupload_follows_the_hubs_rules(lfs):
    api = HfApi(endpoint=lfs.endpoint)
    api.create_repo("lfs/rules")
    gitattributes = api.hf_hub_download("lfs/rules", ".gitattributes")
    patterns = Path(gitattributes).read_text()
    for pattern in ("*.parquet", "*.mp4", "*.gif", "*.png", "*.safetensors"):
        assert f"{pattern} filter=lfs diff=lfs merge=lfs -text" in patterns

    def modes(files: dict[str, bytes], repo: str = "lfs/rules") -> dict[str, str]:
        import base64

        body = {"files": [{"path": p, "sample": base64.b64encode(d[:512]).decode(), "size": len(d)} for p, d in files.items()]}
        r = requests.post(f"{lfs.endpoint}/api/models/{repo}/preupload/main", json=body, timeout=10)
        r.raise_for_status()
        return {f["path"]: f["uploadMode"] for f in r.json()["files"]}

    got = modes(
        {
            "a.txt": b"text",
            "deep/x/img.PNG.png": b"\x89PNG....",
            "saved_model/v1/variables.data": b"text",
            "weights.txt": b"\x00\x01binary",
            "latin1.txt": "caf\xe9 ".encode("latin-1"),
            "cut.txt": b"a" + "é".encode() * 300,  # the 512-byte sample cuts a character: still text
            "empty.parquet": b"",
        }
    )
    assert got == {
        "a.txt": "regular",
        "deep/x/img.PNG.png": "lfs",
        "saved_model/v1/variables.data": "lfs",
        "weights.txt": "lfs",
        "latin1.txt": "lfs",
        "cut.txt": "regular",
        "empty.parquet": "regular",
    }
    # a repo's own .gitattributes decides: untrack *.parquet, track *.txt under logs/
    api.upload_file(
        path_or_fileobj=b"*.parquet -filter\nlogs/**/*.txt filter=lfs diff=lfs merge=lfs -text\n",
        path_in_repo=".gitattributes",
        repo_id="lfs/rules",
    )
    assert modes({"t.parquet": b"PAR1", "logs/a/b.txt": b"x", "b.txt": b"x"}) == {
        "t.parquet": "regular",
        "logs/a/b.txt": "lfs",
        "b.txt": "regular",
    }


def test_wrong_bytes_forged_urls_and_missing_objects_are_refused(lfs):
    api = HfApi(endpoint=lfs.endpoint)
    api.create_repo("lfs/refuse")
    head = api.model_info("lfs/refuse").sha
    data = os.urandom(100_000)
    oid = _sha(data)
    base = f"{lfs.endpoint}/lfs/refuse.git/info/lfs/objects"
    lfs_json = {"Accept": "application/vnd.git-lfs+json", "Content-Type": "application/vnd.git-lfs+json"}
    batch = requests.post(
        f"{base}/batch",
        headers=lfs_json,
        data=json.dumps({"operation": "upload", "transfers": ["basic"], "objects": [{"oid": oid, "size": len(data)}]}),
        timeout=10,
    )
    assert batch.status_code == 200, batch.text
    (obj,) = batch.json()["objects"]
    href = obj["actions"]["upload"]["href"]

    wrong = requests.put(href, data=os.urandom(len(data)), timeout=10)  # right size, other bytes
    assert wrong.status_code == 400 and wrong.headers["X-Error-Code"] == "LfsChecksumMismatch"
    assert oid in wrong.headers["X-Error-Message"] and "upload the file again" in wrong.headers["X-Error-Message"]
    assert requests.put(href, data=data + b"x", timeout=10).status_code == 400  # more bytes than announced
    forged = href.replace("signature=", "signature=0")
    assert requests.put(forged, data=data, timeout=10).status_code == 403
    other_oid = _sha(b"other")
    assert requests.put(href.replace(oid, other_oid), data=b"other", timeout=10).status_code == 403
    # nothing half-written became a blob
    assert requests.post(f"{base}/verify", json={"oid": oid, "size": len(data)}, timeout=10).status_code == 404
    assert not list(lfs.root.rglob(oid)) and not list((lfs.root / "tmp").iterdir())

    # a commit naming an object never uploaded is refused, and the branch does not move
    payload = "\n".join(
        json.dumps(line)
        for line in (
            {"key": "header", "value": {"summary": "sneak", "description": ""}},
            {"key": "lfsFile", "value": {"path": "x.bin", "algo": "sha256", "oid": oid, "size": len(data)}},
        )
    )
    r = requests.post(
        f"{lfs.endpoint}/api/models/lfs/refuse/commit/main",
        data=payload,
        headers={"Content-Type": "application/x-ndjson"},
        timeout=10,
    )
    assert r.status_code == 400 and r.headers["X-Error-Code"] == "LfsObjectMissing" and "x.bin" in r.json()["error"]
    assert api.model_info("lfs/refuse").sha == head

    # the right bytes: stored, verified, committed
    assert requests.put(href, data=data, timeout=10).status_code == 200
    assert requests.post(f"{base}/verify", json={"oid": oid, "size": len(data)}, timeout=10).status_code == 200
    assert requests.post(f"{lfs.endpoint}/api/models/lfs/refuse/commit/main", data=payload, timeout=10).status_code == 200
    assert hf_hub_download("lfs/refuse", "x.bin") and Path(hf_hub_download("lfs/refuse", "x.bin")).read_bytes() == data
    # another repo cannot commit that object without uploading it itself
    api.create_repo("lfs/other")
    r = requests.post(f"{lfs.endpoint}/api/models/lfs/other/commit/main", data=payload, timeout=10)
    assert r.status_code == 400 and r.headers["X-Error-Code"] == "LfsObjectMissing"


def test_lfs_writes_need_the_token_before_any_body_is_read(hub_with_token):
    base = f"{hub_with_token.endpoint}/whoever/repo.git/info/lfs/objects"
    for route in ("batch", "verify"):
        r = requests.post(f"{base}/{route}", data=b"{}", timeout=10)
        assert r.status_code == 401 and "token" in r.headers["X-Error-Message"]
    # with the token: the client's own LFS path works against a token server
    api = hub_with_token.api
    api.create_repo("tok/lfs", private=True)
    data = os.urandom(2 * MiB)
    api.upload_file(path_or_fileobj=data, path_in_repo="w.bin", repo_id="tok/lfs")
    assert _sha(data) in _stored(hub_with_token.server)
    assert Path(hf_hub_download("tok/lfs", "w.bin")).read_bytes() == data


def test_an_interrupted_lfs_download_resumes_with_a_range_request(lfs, tmp_path):
    api = HfApi(endpoint=lfs.endpoint)
    api.create_repo("lfs/resume")
    # the client writes what it received in pieces of DOWNLOAD_CHUNK_SIZE (10 MiB): a resume can only
    # start after the first one, so the connection drops after 12 MiB of 24
    data = os.urandom(24 * MiB)
    sha = api.upload_file(path_or_fileobj=data, path_in_repo="cam.mp4", repo_id="lfs/resume").oid
    assert _sha(data) in _stored(lfs)
    lfs.faults.inject({"match": rf"GET /lfs/resume/resolve/{sha}/cam\.mp4", "action": "drop", "after_bytes": 12 * MiB})
    cache = tmp_path / "cache"
    try:
        path = hf_hub_download("lfs/resume", "cam.mp4", revision=sha, cache_dir=cache)  # 1.x resumes in the call
    except _compat.TRANSFER_ERRORS:  # 0.x gives up on a broken body, and keeps the partial file
        assert _compat.HF_HUB_MAJOR < 1
        partial = list(cache.rglob("*.incomplete"))
        assert partial and 0 < partial[0].stat().st_size < len(data)
        path = hf_hub_download("lfs/resume", "cam.mp4", revision=sha, cache_dir=cache)  # the next call resumes
    finally:
        lfs.faults.heal()
    assert Path(path).read_bytes() == data
    ranges = re.findall(rf"lfs: serving bytes (\d+)-\d+ of {_sha(data)}", lfs.output())
    assert ranges and int(ranges[-1]) >= constants.DOWNLOAD_CHUNK_SIZE  # the rest came by Range, not from the start


def test_upload_large_folder_goes_through_lfs(lfs, tmp_path):
    folder = tmp_path / "big-folder"
    files = {
        "dataset/data/chunk-000/file-000.parquet": b"PAR1" + os.urandom(300_000),
        "dataset/meta/info.json": b'{"fps": 10}',
        "media/rollout.gif": b"GIF89a" + os.urandom(50_000),
        "weights.bin": os.urandom(5 * MiB),
    }
    for rel, data in files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_bytes(data)
    api = HfApi(endpoint=lfs.endpoint)
    api.create_repo("lfs/large-folder")
    api.upload_large_folder(repo_id="lfs/large-folder", folder_path=folder, repo_type="model", num_workers=2)
    stored = _stored(lfs)
    for rel in ("dataset/data/chunk-000/file-000.parquet", "media/rollout.gif", "weights.bin"):
        assert _sha(files[rel]) in stored, rel
    assert _sha(files["dataset/meta/info.json"]) not in stored
    assert set(api.list_repo_files("lfs/large-folder")) == {".gitattributes", *files}
    for rel, data in files.items():
        assert Path(hf_hub_download("lfs/large-folder", rel, cache_dir=tmp_path / "c")).read_bytes() == data


def test_xet_is_not_offered_and_hub_envs_pushes_go_through_lfs_where_the_client_would_use_xet(lfs, tmp_path):
    r = requests.get(f"{lfs.endpoint}/api/models/lfs/x/xet-write-token/main", timeout=10)
    assert r.status_code == 501 and "HF_HUB_DISABLE_XET=1" in r.headers["X-Error-Message"]
    api = HfApi(endpoint=lfs.endpoint)
    api.create_repo("lfs/pushed")
    assert requests.get(f"{lfs.endpoint}/api/models/lfs/pushed?expand=xetEnabled", timeout=10).json()["xetEnabled"] is False
    folder = tmp_path / "pushed"
    (folder / "dataset").mkdir(parents=True)
    table = b"PAR1" + os.urandom(20_000)
    (folder / "dataset" / "file-000.parquet").write_bytes(table)
    (folder / "env.py").write_text("print('hi')\n")
    # as a user without HF_HUB_DISABLE_XET would: huggingface_hub 1.x would take Xet if hf_xet is installed
    saved = constants.HF_HUB_DISABLE_XET
    constants.HF_HUB_DISABLE_XET = False
    try:
        sha = hub_io.publish_folder(folder, "lfs/pushed", parent_commit=None, remote_files=[], message="push")
        assert constants.HF_HUB_DISABLE_XET is False  # restored after the push
    finally:
        constants.HF_HUB_DISABLE_XET = saved
    assert _sha(table) in _stored(lfs)
    assert Path(hf_hub_download("lfs/pushed", "dataset/file-000.parquet", revision=sha)).read_bytes() == table


def test_an_lfs_commit_line_must_match_the_stored_size(lfs):
    api = HfApi(endpoint=lfs.endpoint)
    api.create_repo("lfs/size")
    data = os.urandom(300_000)
    api.upload_file(path_or_fileobj=data, path_in_repo="a.bin", repo_id="lfs/size")
    payload = "\n".join(
        json.dumps(line)
        for line in (
            {"key": "header", "value": {"summary": "wrong size"}},
            {"key": "lfsFile", "value": {"path": "b.bin", "algo": "sha256", "oid": _sha(data), "size": 5}},
        )
    )
    r = requests.post(f"{lfs.endpoint}/api/models/lfs/size/commit/main", data=payload, timeout=10)
    assert r.status_code == 400 and "not 5" in r.json()["error"]
    assert api.list_repo_files("lfs/size") == [".gitattributes", "a.bin"]


def _rss_mb(pid: int, field: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no {field} in /proc/{pid}/status")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the server's peak RSS from /proc")
def test_a_large_push_does_not_grow_the_servers_memory(tmp_path):
    # 144 MiB through LFS into a fresh server, a 96 MiB file in two 48 MiB parts and a 48 MiB file in one
    # PUT: streamed to disk, so its peak RSS grows by a few buffers, less than any file or part (the inline
    # path held a whole file's base64 line). The 1 GiB figure is the benchmark `server_push_rss_mb`.
    folder = tmp_path / "big"
    folder.mkdir()
    sizes = {"a.parquet": 96 * MiB, "c.bin": 48 * MiB}
    for name, size in sizes.items():
        with open(folder / name, "wb") as f:
            for _ in range(size // MiB):
                f.write(os.urandom(MiB))
    env = {"HUB_ENVS_SERVER_LFS_CHUNK_MB": "48", "HUB_ENVS_SERVER_FSYNC": "0"}
    with HubServer(tmp_path / "hub-data", env=env) as server, hub_environment(server.endpoint, tmp_path / "home"):
        api = HfApi(endpoint=server.endpoint)
        api.create_repo("mem/big")
        before = _rss_mb(server.process.pid, "VmRSS")
        api.upload_folder(folder_path=folder, repo_id="mem/big", commit_message="big")
        peak = _rss_mb(server.process.pid, "VmHWM")
        stored = _stored(server)
        assert len(stored) == 2 and set(stored.values()) == {"basic", "multipart"}
    assert peak - before < 48, f"server RSS grew from {before:.0f} to a peak of {peak:.0f} MiB during a 144 MiB push"
