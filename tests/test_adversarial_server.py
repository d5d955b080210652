"""Red-team findings against the loopback Hub server, each reproduced against a real server.

Every test starts a real server (``hub_envs.testing.HubServer``, through the ``hub`` fixtures) and
attacks it as a client would: with the unmodified ``huggingface_hub`` client where it can send the
attack, with raw HTTP (``requests``, or a socket) where it cannot. All traffic goes to 127.0.0.1,
with bounded request counts, sizes and client timeouts. The first part holds the fixed findings,
the second the attacks that already failed, so they keep failing.

Memory is read from ``/proc/<server pid>/status``: ``VmHWM`` is the peak resident set size.
"""

from __future__ import annotations

import base64
import hashlib
import http.client
import json
import socket
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from urllib.parse import unquote

import pytest
import requests
from huggingface_hub import CommitOperationAdd, CommitOperationDelete, HfApi, hf_hub_download
from huggingface_hub.errors import BadRequestError, HfHubHTTPError, RepositoryNotFoundError

from hub_envs.errors import ConfigError
from hub_envs.testing import HubServer, HubServerError, hub_environment

MiB = 1024 * 1024
TIMEOUT = 30  # client timeout (s) of requests that used to hang: a hang fails the test, never blocks it

pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc/<pid>/status")


# --- helpers ------------------------------------------------------------------------------------


def _mem_mib(server: HubServer, field: str = "VmHWM") -> float:
    """The server process's resident memory (``VmRSS``) or its peak so far (``VmHWM``), in MiB."""
    for line in Path(f"/proc/{server.process.pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no {field} in /proc/{server.process.pid}/status")


def _auth(token: str | None) -> dict:
    return {"Authorization": f"Bearer {token}"} if token else {}


def _ndjson(*lines: dict) -> bytes:
    return b"".join(json.dumps(line).encode() + b"\n" for line in lines)


def _header(summary: str = "attack", **extra) -> dict:
    return {"key": "header", "value": {"summary": summary, "description": "", **extra}}


def _file(path: str, data: bytes) -> dict:
    return {"key": "file", "value": {"content": base64.b64encode(data).decode(), "path": path, "encoding": "base64"}}


def _raw_commit(
    endpoint: str, repo_id: str, body, *, repo_type: str = "model", token: str | None = None, timeout: float = TIMEOUT
) -> requests.Response:
    return requests.post(
        f"{endpoint}/api/{repo_type}s/{repo_id}/commit/main",
        data=body,
        headers={"Content-Type": "application/x-ndjson", **_auth(token)},
        timeout=timeout,
    )


def _commit(api: HfApi, repo_id: str, files: dict[str, bytes], **kw) -> str:
    ops = [CommitOperationAdd(path_in_repo=p, path_or_fileobj=d) for p, d in files.items()]
    return api.create_commit(repo_id, ops, commit_message=kw.pop("message", "update"), **kw).oid


def _git_blob_oid(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def _partial_request(
    endpoint: str, method: str, path: str, declared: int, sent: bytes = b"", headers: dict | None = None, timeout: float = 15
) -> tuple[int, dict[str, str]]:
    """Announce a ``declared``-byte body, send only ``sent`` of it, and read the answer.

    A server that reads the whole body before answering never answers: the socket times out.
    """
    host, port = endpoint.removeprefix("http://").split(":")
    lines = [
        f"{method} {path} HTTP/1.1",
        f"Host: {host}:{port}",
        f"Content-Length: {declared}",
        "Content-Type: application/json",
    ] + [f"{k}: {v}" for k, v in (headers or {}).items()]
    with socket.create_connection((host, int(port)), timeout=timeout) as sock:
        sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode() + sent)
        received = b""
        while b"\r\n\r\n" not in received:
            chunk = sock.recv(65536)
            if not chunk:
                break
            received += chunk
    head = received.split(b"\r\n\r\n", 1)[0].decode("latin-1").split("\r\n")
    status = int(head[0].split()[1])
    fields = {k.strip().lower(): v.strip() for k, v in (h.split(":", 1) for h in head[1:] if ":" in h)}
    return status, fields


def _assert_error(response: requests.Response, status: int | tuple[int, ...], *words: str) -> None:
    statuses = status if isinstance(status, tuple) else (status,)
    assert response.status_code in statuses, (response.status_code, response.text[:300])
    message = response.headers.get("X-Error-Message", "")
    assert message, "a refusal carries X-Error-Message, so the client raises a typed error"
    for word in words:
        assert word in message, (word, message)


# === fixed findings ==============================================================================

# --- 1. (High) a YAML alias bomb or deep nesting in a model card ---------------------------------

BILLION_LAUGHS = (
    b"---\n"
    b'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
    b"b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\n"
    b"c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
    b"d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\n"
    b"e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\n"
    b"f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]\n"
    b"g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]\n"
    b"h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]\n"
    b"i: &i [*h,*h,*h,*h,*h,*h,*h,*h,*h]\n"
    b"---\n# lol\n"
)


def test_card_alias_bomb_and_deep_nesting_do_not_take_the_server_down(hub):
    api, endpoint = hub.api, hub.endpoint
    assert len(BILLION_LAUGHS) < 600  # a few hundred bytes; 9**9 strings once expanded as JSON
    readmes = {
        "bomb": BILLION_LAUGHS,
        "deep-flow": b"---\nx: " + b"[" * 10_000 + b"]" * 10_000 + b"\n---\n",  # 10,000 levels deep
        "deep-block": b"---\nx: " + b"- " * 10_000 + b"end\n---\n",
        "deep-map": b"---\nx: " + b"{a: " * 10_000 + b"1" + b"}" * 10_000 + b"\n---\n",
        "huge": b"---\n" + b"".join(b"k%d: %s\n" % (i, b"v" * 60) for i in range(1500)) + b"---\n",  # ~100 KiB
        "dates": b"---\nlicense: mit\ntags: [robotics]\nreleased: 2024-05-01\nwhen: 2024-05-01 12:00:00\n"
        b"odd: !!set {a: null}\nraw: !!binary aGk=\nnan: .nan\n1: one\n---\n",
    }
    for name, readme in readmes.items():
        api.create_repo(f"alice/{name}")
        # raw: the client would first ask /api/validate-yaml, which refuses most of these (below)
        response = _raw_commit(endpoint, f"alice/{name}", _ndjson(_header(), _file("README.md", readme)))
        assert response.status_code == 200, (name, response.text[:300])
    api.create_repo("alice/normal")
    _commit(api, "alice/normal", {"README.md": b"---\nlicense: mit\ntags:\n- robotics\n---\n", "a.txt": b"a"})

    # each answers at once (a client timeout, not a speed assertion), without cardData
    for name in ("bomb", "deep-flow", "deep-block", "deep-map", "huge"):
        info = api.model_info(f"alice/{name}", timeout=TIMEOUT)
        assert info.card_data is None and info.tags == [], name
        assert [s.rfilename for s in info.siblings] == [".gitattributes", "README.md"]
    dates = api.model_info("alice/dates", timeout=TIMEOUT)  # YAML dates, sets, binary: JSON, not a 500
    assert dates.card_data["license"] == "mit" and dates.tags == ["robotics"]
    card = requests.get(f"{endpoint}/api/models/alice/dates", timeout=TIMEOUT).json()["cardData"]
    assert card["released"] == "2024-05-01" and card["when"].startswith("2024-05-01")
    assert card["odd"] == ["a"] and card["raw"] == "aGk=" and card["nan"] is None and card["1"] == "one"
    assert api.model_info("alice/normal", timeout=TIMEOUT).card_data["license"] == "mit"

    # the listing holds every repo
    listing = requests.get(f"{endpoint}/api/models", timeout=TIMEOUT)
    assert listing.status_code == 200, listing.text[:300]
    assert {m["id"] for m in listing.json()} == {f"alice/{n}" for n in [*readmes, "normal"]}
    assert len({m.id for m in api.list_models(author="alice")}) == len(readmes) + 1
    # the other repos' routes keep working
    assert Path(hf_hub_download("alice/normal", "a.txt")).read_bytes() == b"a"
    assert Path(hf_hub_download("alice/bomb", "README.md")).read_bytes() == BILLION_LAUGHS
    assert _commit(api, "alice/normal", {"b.txt": b"b"})
    assert _mem_mib(hub.server) < 500, f"server peak RSS {_mem_mib(hub.server):.0f} MiB"

    # /api/validate-yaml (which the client calls before committing a README) refuses them
    for name in ("bomb", "deep-flow", "huge"):
        with pytest.raises(ValueError, match="Invalid metadata in README.md"):
            api.upload_file(path_or_fileobj=readmes[name], path_in_repo="README.md", repo_id="alice/normal")
    assert _mem_mib(hub.server) < 500


# --- 2. (Medium) request bodies: authentication first, size caps, parsing off the event loop -----


def _write_routes(repo: str) -> list[tuple[str, str]]:
    return [
        ("POST", "/api/repos/create"),
        ("DELETE", "/api/repos/delete"),
        ("POST", "/api/validate-yaml"),
        ("POST", f"/api/models/{repo}/preupload/main"),
        ("POST", f"/api/models/{repo}/commit/main"),
        ("POST", f"/api/models/{repo}/branch/dev"),
        ("DELETE", f"/api/models/{repo}/branch/dev"),
        ("POST", f"/api/models/{repo}/tag/main"),
        ("DELETE", f"/api/models/{repo}/tag/v1"),
        ("PUT", f"/api/models/{repo}/settings"),
    ]


def test_anonymous_big_post_to_a_token_server_is_refused_before_its_body_is_read(hub_with_token):
    hub = hub_with_token
    hub.api.create_repo("alice/env")
    before = hub.api.model_info("alice/env").sha
    # 96 MiB announced, 1 MiB sent: the 401 must come back without the rest
    for method, path in _write_routes("alice/env"):
        status, headers = _partial_request(hub.endpoint, method, path, declared=96 * MiB, sent=b"{" * MiB)
        assert status == 401, (method, path, status)
        assert "Authentication required" in headers.get("x-error-message", ""), (method, path)
    # the whole 96 MiB sent: still 401, and the server never holds it
    peak = _mem_mib(hub.server)
    big = b"x" * (96 * MiB)
    for path in ("/api/repos/create", "/api/models/alice/env/commit/main", "/api/models/alice/env/preupload/main"):
        response = requests.post(hub.endpoint + path, data=big, timeout=TIMEOUT)
        assert response.status_code == 401, (path, response.status_code)
    assert _mem_mib(hub.server) - peak < 48, f"peak RSS grew {_mem_mib(hub.server) - peak:.0f} MiB"
    assert hub.api.model_info("alice/env").sha == before


@pytest.fixture
def capped_hub(tmp_path):
    """A token server with small caps: 16 MiB bodies, 4 MiB commit lines (env variables of run())."""
    env = {"HUB_ENVS_SERVER_MAX_BODY_MB": "16", "HUB_ENVS_SERVER_MAX_LINE_MB": "4", "HUB_ENVS_SERVER_MAX_LFS_MB": "8"}
    with HubServer(tmp_path / "capped-data", token="capped-token", env=env) as server:
        with hub_environment(server.endpoint, tmp_path / "capped-home", token="capped-token"):
            yield server


def test_oversize_bodies_and_lines_get_413_naming_the_limit(capped_hub):
    server, token = capped_hub, "capped-token"
    api = HfApi(endpoint=server.endpoint, token=token)
    api.create_repo("alice/env")
    head = api.model_info("alice/env").sha

    # announced too large: refused before a byte of it is read
    status, headers = _partial_request(
        server.endpoint, "POST", "/api/models/alice/env/commit/main", declared=32 * MiB, headers=_auth(token)
    )
    assert status == 413 and "16 MiB" in headers["x-error-message"]
    assert "HUB_ENVS_SERVER_MAX_BODY_MB" in headers["x-error-message"] and "--max_body_mb" in headers["x-error-message"]

    def streamed(lines):  # chunked: no Content-Length, the server counts as it reads
        yield from lines

    lines = [_ndjson(_header())] + [_ndjson(_file(f"f{i}.bin", bytes(MiB))) for i in range(20)]  # ~27 MiB
    response = _raw_commit(server.endpoint, "alice/env", streamed(lines), token=token)
    _assert_error(response, 413, "16 MiB", "HUB_ENVS_SERVER_MAX_BODY_MB")

    long_line = _ndjson(_file("long.bin", bytes(4 * MiB)))  # 5.3 MiB of base64 on one line
    response = _raw_commit(server.endpoint, "alice/env", streamed([_ndjson(_header()), long_line]), token=token)
    _assert_error(response, 413, "4 MiB", "HUB_ENVS_SERVER_MAX_LINE_MB", "--max_line_mb")

    response = requests.post(
        f"{server.endpoint}/api/models/alice/env/preupload/main",
        headers=_auth(token),
        json={"files": [{"path": "x" * 100, "sample": "", "size": 1}] * 200_000},
        timeout=TIMEOUT,
    )
    _assert_error(response, 413, "16 MiB")  # JSON bodies: at most the body cap (and 32 MiB)
    assert api.model_info("alice/env").sha == head  # nothing was committed

    # the real client gets a typed error naming the limit: a text file goes inline (regular, under 10 MiB)...
    with pytest.raises(HfHubHTTPError) as exc:
        _commit(api, "alice/env", {"too-big.txt": b"a" * (4 * MiB)})
    assert exc.value.response.status_code == 413 and "HUB_ENVS_SERVER_MAX_LINE_MB" in str(exc.value)
    # ... a binary one through LFS, whose cap is per file
    with pytest.raises(HfHubHTTPError) as exc:
        _commit(api, "alice/env", {"too-big.bin": bytes(9 * MiB)})
    assert exc.value.response.status_code == 413 and "HUB_ENVS_SERVER_MAX_LFS_MB" in str(exc.value)
    assert api.model_info("alice/env").sha == head
    # and files under the caps still commit (a line over 1 MiB takes the large-line path)
    payload = b"0123456789abcde\n" * (160 * 1024)  # 2.5 MiB of text: a 3.3 MiB line
    sha = _commit(api, "alice/env", {"a.txt": payload, "small.txt": b"s", "b.bin": bytes(6 * MiB)})
    siblings = {s.rfilename: s for s in api.model_info("alice/env", files_metadata=True).siblings}
    assert siblings["a.txt"].blob_id == _git_blob_oid(payload) and siblings["a.txt"].size == len(payload)
    assert Path(hf_hub_download("alice/env", "a.txt", revision=sha)).read_bytes() == payload
    assert siblings["b.bin"].lfs.size == 6 * MiB  # over the 4 MiB line cap, under the 8 MiB LFS cap


def test_large_lines_must_be_base64_file_lines(hub):
    hub.api.create_repo("alice/env")
    data = bytes(range(256)) * (8 * 1024)  # 2 MiB: a large line
    escaped = json.dumps(_file("slashes.bin", data)).replace("/", "\\/").encode() + b"\n"  # "\/": also valid JSON
    reordered = (
        json.dumps(
            {"key": "file", "value": {"path": "last.bin", "encoding": "base64", "content": base64.b64encode(data).decode()}}
        ).encode()
        + b"\n"
    )
    response = _raw_commit(hub.endpoint, "alice/env", _ndjson(_header()) + escaped + reordered)
    assert response.status_code == 200, response.text[:300]
    assert Path(hf_hub_download("alice/env", "slashes.bin")).read_bytes() == data
    assert Path(hf_hub_download("alice/env", "last.bin")).read_bytes() == data
    for bad in (
        _ndjson(_header(description="d" * (2 * MiB))),  # a large line that is not a file
        _ndjson(_header(), {"key": "file", "value": {"content": "a" * (2 * MiB), "path": "x", "encoding": "utf-8"}}),
        _ndjson(_header(), {"key": "file", "value": {"content": "A" * (2 * MiB) + "=A==", "path": "x", "encoding": "base64"}}),
        _ndjson(_header(), {"key": "file", "value": {"content": "A" * (2 * MiB + 1), "path": "x", "encoding": "base64"}}),
        _ndjson(
            _header(),
            {
                "key": "file",
                "value": {"content": "A" * (2 * MiB), 'x"content': "\u0000hub-envs:content", "path": "x", "encoding": "base64"},
            },
        ),
    ):
        response = _raw_commit(hub.endpoint, "alice/env", bad)
        _assert_error(response, 400, "Malformed commit payload")
    assert sorted(hub.api.list_repo_files("alice/env")) == [".gitattributes", "last.bin", "slashes.bin"]


@pytest.fixture
def hub_with_long_lines(tmp_path):
    """An open server whose operator raised the commit-line cap to 512 MiB (the default, 16 MiB, fits the largest
    file huggingface_hub sends inline): to check that even such lines are parsed off the event loop."""
    with HubServer(tmp_path / "long-data", env={"HUB_ENVS_SERVER_MAX_LINE_MB": "512"}) as server:
        with hub_environment(server.endpoint, tmp_path / "long-home"):
            yield SimpleNamespace(server=server, endpoint=server.endpoint, api=HfApi(endpoint=server.endpoint))


def test_small_requests_are_served_while_a_big_upload_is_in_flight(hub_with_long_lines):
    hub = hub_with_long_lines
    api = hub.api
    api.create_repo("alice/env")
    api.create_repo("alice/other")
    data = bytes(range(256)) * (768 * 1024)  # 192 MiB: 256 MiB of base64 on one line
    encoded = base64.b64encode(data)
    before = _mem_mib(hub.server)

    def body():
        yield _ndjson(_header("big upload"))
        yield b'{"key": "file", "value": {"content": "'
        view = memoryview(encoded)
        for i in range(0, len(view), 8 * MiB):
            yield view[i : i + 8 * MiB]
        yield b'", "path": "big.bin", "encoding": "base64"}}\n'

    result: dict = {}
    upload = threading.Thread(target=lambda: result.update(r=_raw_commit(hub.endpoint, "alice/env", body(), timeout=120)))
    upload.start()
    latencies = []
    while upload.is_alive():  # while the upload is sent, then parsed and stored
        start = time.monotonic()
        assert requests.get(f"{hub.endpoint}/api/whoami-v2", timeout=2).status_code == 200
        assert api.model_info("alice/other", timeout=2).sha
        latencies.append(time.monotonic() - start)
        time.sleep(0.02)
    upload.join()
    assert result["r"].status_code == 200, result["r"].text[:300]
    assert len(latencies) >= 3
    head = requests.head(f"{hub.endpoint}/alice/env/resolve/main/big.bin", timeout=TIMEOUT)
    assert head.headers["ETag"].strip('"') == _git_blob_oid(data) and int(head.headers["Content-Length"]) == len(data)
    peak = _mem_mib(hub.server) - before
    print(
        f"\nbig upload: {len(latencies)} small requests, max {max(latencies) * 1000:.0f} ms, "
        f"median {sorted(latencies)[len(latencies) // 2] * 1000:.0f} ms; server peak RSS +{peak:.0f} MiB",
        file=sys.stderr,
    )
    assert peak < 256 + 192, f"server peak RSS grew {peak:.0f} MiB for a 256 MiB line"


# --- 3. (Low) commit cache keyed without the repo type; 500s leaking paths ----------------------


def test_a_private_models_commits_are_not_readable_through_a_same_named_dataset(hub_with_token):
    hub = hub_with_token
    hub.api.create_repo("alice/twin", private=True)
    secret_sha = _commit(hub.api, "alice/twin", {"secret-plans.txt": b"top secret"})
    hub.api.create_repo("alice/twin", repo_type="dataset")  # public, same name
    hub.api.model_info("alice/twin", revision=secret_sha)  # the owner reads the model: its commit is cached

    for token in (None, hub.token):
        for url in (
            f"/api/datasets/alice/twin/revision/{secret_sha}",
            f"/api/datasets/alice/twin/tree/{secret_sha}",
            f"/datasets/alice/twin/resolve/{secret_sha}/secret-plans.txt",
        ):
            response = requests.get(hub.endpoint + url, headers=_auth(token), timeout=TIMEOUT)
            assert response.status_code == 404, (url, response.status_code, response.text[:200])
            assert response.headers.get("X-Error-Code") == "RevisionNotFound"
            assert b"secret" not in response.content and str(hub.root) not in response.text
    assert hub.api.model_info("alice/twin", revision=secret_sha).sha == secret_sha  # the model is intact


def test_internal_errors_answer_a_generic_message_without_paths(hub):
    hub.api.create_repo("alice/env")
    _commit(hub.api, "alice/env", {"a.txt": b"content"})
    blob = next(p for p in hub.root.rglob(hashlib.sha256(b"content").hexdigest()))
    blob.unlink()  # a store damaged on disk: reading the file fails inside the server
    response = requests.get(f"{hub.endpoint}/alice/env/resolve/main/a.txt", timeout=TIMEOUT)
    assert response.status_code == 500
    everything = response.text + json.dumps(dict(response.headers))
    for leak in (str(hub.root), "/blobs/", "FileNotFoundError", "Errno"):
        assert leak not in everything, leak
    assert "server's log" in response.headers["X-Error-Message"]
    assert "FileNotFoundError" in hub.server.output()  # the details are logged server-side


# --- 4. (Low) "private": "false" made a private repo --------------------------------------------


def test_private_and_visibility_must_be_what_the_clients_send(hub):
    def create(name: str, **fields) -> requests.Response:
        body = {"name": name, "organization": "alice", **fields}
        return requests.post(f"{hub.endpoint}/api/repos/create", json=body, timeout=TIMEOUT)

    for value in ("false", "true", 0, 1, "", [], {}):
        _assert_error(create("refused", private=value), 400, "private")
    for value in (1, True, ["private"], {"a": 1}, "PRIVATE"):
        _assert_error(create("refused", visibility=value), 400, "visibility")
    assert not hub.api.repo_exists("alice/refused")
    assert create("open", private=None).status_code == 200  # null: not said, public
    assert hub.api.model_info("alice/open").private is False
    for fields in ({"private": "false"}, {"private": "true"}, {"visibility": False}):
        response = requests.put(f"{hub.endpoint}/api/models/alice/open/settings", json=fields, timeout=TIMEOUT)
        _assert_error(response, 400)
    assert hub.api.model_info("alice/open").private is False


# --- 5. (Low) control characters and over-long names in file paths ------------------------------


def test_control_characters_and_long_names_in_paths_are_refused(hub):
    api, endpoint = hub.api, hub.endpoint
    api.create_repo("alice/env")
    head = api.model_info("alice/env").sha
    refused = [
        "next\u0085line.txt",  # C1 NEL
        "\u009b31mred.txt",  # C1 CSI: an 8-bit terminal escape
        "a\u0080b",
        "a\u009fb",
        "del\x7f.txt",
        "tab\t.txt",
        "cr\r.txt",
        "esc\x1b[31m.txt",  # C0 and DEL
        "a" * 256,  # 256 bytes
        "é" * 128,  # 128 characters, 256 bytes of UTF-8
        "ok/" + "b" * 256 + "/c.txt",
        "\ud800.txt",  # a lone surrogate: not Unicode at all
    ]
    for path in refused:
        response = _raw_commit(endpoint, "alice/env", _ndjson(_header(), _file(path, b"x")))
        _assert_error(response, 400, "Invalid path")
    for path in ("next\u0085line.txt", "\u009b31mred.txt", "a" * 256):  # through the real client too
        with pytest.raises(BadRequestError):
            _commit(api, "alice/env", {path: b"x"})
    for url in (
        "/alice/env/resolve/main/a%C2%85b",
        "/api/models/alice/env/tree/main/a%C2%9Bb",
        "/alice/env/resolve/main/" + "a" * 256,
        "/alice/env/resolve/main/a%7Fb",
    ):
        assert requests.get(endpoint + url, timeout=TIMEOUT).status_code == 400, url
    for branch in ("a%C2%85b", "a%C2%9B31m", "a%7Fb"):  # and in branch and tag names
        assert requests.post(f"{endpoint}/api/models/alice/env/branch/{branch}", timeout=TIMEOUT).status_code == 400
        response = requests.post(f"{endpoint}/api/models/alice/env/tag/main", json={"tag": unquote(branch)}, timeout=TIMEOUT)
        assert response.status_code == 400
    assert api.model_info("alice/env").sha == head and [b.name for b in api.list_repo_refs("alice/env").branches] == ["main"]
    # the limits: 255 bytes is fine, and so are printable non-ASCII names
    fine = {"a" * 255: b"1", "é" * 127 + "a": b"2", "ünï cødé ✓.txt": b"3"}
    sha = _commit(api, "alice/env", fine)
    for path, data in fine.items():
        assert Path(hf_hub_download("alice/env", path, revision=sha)).read_bytes() == data


# --- 6. (Low) 500 instead of 4xx; Range edge cases; validate-yaml --------------------------------


def test_malformed_requests_get_4xx_not_500(hub):
    api, endpoint = hub.api, hub.endpoint
    api.create_repo("alice/env")
    head = _commit(api, "alice/env", {"a.txt": b"0123456789", "empty.txt": b""})

    deep = "[" * 100_000 + "]" * 100_000
    for body in (
        b'{"key": "header", "value": ' + deep.encode() + b"}\n",
        _ndjson(_header()) + b'{"key": "file", "value": {"path": "x", "content": ' + deep.encode() + b"}}\n",
        _ndjson(_header(), {"key": "file", "value": {"path": "x", "content": ["a"], "encoding": "base64"}}),
        _ndjson(_header(), {"key": "file", "value": {"path": "x", "content": 5}}),
        _ndjson(_header(), {"key": "file", "value": {"path": "x", "content": "Zm9v!", "encoding": "base64"}}),
        _ndjson(_header(), {"key": "lfsFile", "value": {"path": "x", "oid": ["a"]}}),
        _ndjson(_header(), {"key": ["file"], "value": {"path": "x"}}),
        _ndjson({"key": "header", "value": {"summary": ["not", "a", "string"]}}),
        _ndjson({"key": "header", "value": {"summary": "ok", "description": {"a": 1}}}),
        _ndjson({"key": "header", "value": {"summary": "\ud800"}}),
        _ndjson({"key": "header", "value": {"summary": "ok", "parentCommit": 12345}}),
        b"[1, 2]\n",
        b"not json\n",
        b"\xff\xfe\n",
    ):
        response = _raw_commit(endpoint, "alice/env", body)
        assert 400 <= response.status_code < 500, (body[:80], response.status_code, response.text[:200])
        assert response.headers.get("X-Error-Message")
    create = requests.post(f"{endpoint}/api/repos/create", data=('{"name": ' + deep + "}").encode(), timeout=TIMEOUT)
    _assert_error(create, 400, "JSON")

    for start in (5, ["main"], {"a": 1}, "", True):
        response = requests.post(f"{endpoint}/api/models/alice/env/branch/dev", json={"startingPoint": start}, timeout=TIMEOUT)
        _assert_error(response, 400, "startingPoint")
    for body in ({"paths": "a.txt"}, {"paths": [1, 2]}, {"paths": [["a.txt"]]}, [1]):
        response = requests.post(f"{endpoint}/api/models/alice/env/paths-info/main", json=body, timeout=TIMEOUT)
        _assert_error(response, 400)
    for body in ({"files": "x"}, {"files": [{"path": 5}]}, {"files": [1]}):
        response = requests.post(f"{endpoint}/api/models/alice/env/preupload/main", json=body, timeout=TIMEOUT)
        _assert_error(response, 400)
    for body in ({"name": "x", "organization": ["a"]}, {"name": "x", "type": ["model"]}, {"name": 5}):
        _assert_error(requests.post(f"{endpoint}/api/repos/create", json=body, timeout=TIMEOUT), 400)
        _assert_error(requests.delete(f"{endpoint}/api/repos/delete", json=body, timeout=TIMEOUT), (400, 404))
    _assert_error(requests.post(f"{endpoint}/api/models/alice/env/tag/main", json={"tag": 5}, timeout=TIMEOUT), 400)
    _assert_error(requests.post(f"{endpoint}/api/validate-yaml", json={"content": ["---"]}, timeout=TIMEOUT), 400)
    response = requests.post(f"{endpoint}/api/validate-yaml", json={"content": "---\nd: 2024-02-30\n---\n"}, timeout=TIMEOUT)
    assert response.status_code == 400 and response.json()["errors"]  # an impossible date: invalid, not a 500

    # Range: numbers too long for int(), and an empty file
    url = f"{endpoint}/alice/env/resolve/main/a.txt"
    huge = "9" * 4300
    response = requests.get(url, headers={"Range": f"bytes={huge}-"}, timeout=TIMEOUT)
    assert response.status_code == 416 and response.headers["Content-Range"] == "bytes */10"
    response = requests.get(url, headers={"Range": f"bytes=2-{huge}"}, timeout=TIMEOUT)
    assert response.status_code == 206 and response.content == b"23456789"
    assert response.headers["Content-Range"] == "bytes 2-9/10"
    response = requests.get(url, headers={"Range": f"bytes=-{huge}"}, timeout=TIMEOUT)
    assert response.status_code == 206 and response.content == b"0123456789"
    empty = f"{endpoint}/alice/env/resolve/main/empty.txt"
    for method in ("GET", "HEAD"):
        response = requests.request(method, empty, headers={"Range": "bytes=-1"}, timeout=TIMEOUT)
        assert response.status_code in (200, 416) and response.content == b""
        if response.status_code == 200:
            assert "Content-Range" not in response.headers and response.headers["Content-Length"] == "0"
        else:
            assert response.headers["Content-Range"] == "bytes */0"
        response = requests.request(method, empty, headers={"Range": "bytes=0-"}, timeout=TIMEOUT)
        assert response.status_code == 416 and response.headers["Content-Range"] == "bytes */0"
    assert Path(hf_hub_download("alice/env", "empty.txt")).read_bytes() == b""
    assert api.model_info("alice/env").sha == head


def test_validate_yaml_needs_the_token_and_has_a_size_cap(hub_with_token):
    hub = hub_with_token
    url = f"{hub.endpoint}/api/validate-yaml"
    content = {"content": "---\nlicense: mit\n---\n"}
    _assert_error(requests.post(url, json=content, timeout=TIMEOUT), 401, "Authentication required")
    _assert_error(requests.post(url, json=content, headers={"Authorization": "Bearer wrong"}, timeout=TIMEOUT), 401)
    assert requests.post(url, json=content, headers=_auth(hub.token), timeout=TIMEOUT).json() == {"errors": [], "warnings": []}
    big = {"content": "---\nlicense: mit\n---\n" + "x" * (40 * MiB)}
    _assert_error(requests.post(url, json=big, headers=_auth(hub.token), timeout=TIMEOUT), 413, "32 MiB")
    # the client's own check of a README, on the way to a commit
    hub.api.create_repo("alice/env")
    hub.api.upload_file(path_or_fileobj=b"---\nlicense: mit\n---\n# hi\n", path_in_repo="README.md", repo_id="alice/env")
    anonymous = HfApi(endpoint=hub.endpoint, token=False)
    with pytest.raises(HfHubHTTPError) as exc:
        anonymous.upload_file(path_or_fileobj=b"---\nlicense: mit\n---\n", path_in_repo="README.md", repo_id="alice/env")
    assert exc.value.response.status_code == 401


# --- 7. compiled bytecode in env repos ----------------------------------------------------------


def test_bytecode_is_refused_in_env_repos(hub):
    api = hub.api
    api.create_repo("alice/env")
    _commit(api, "alice/env", {"hub_env.json": b"{}", "my_env.py": b"X = 1\n"})  # an env repo: it has a manifest
    head = api.model_info("alice/env").sha
    for path in (
        "__pycache__/my_env.cpython-312.pyc",
        "my_env.pyc",
        "pkg/my_env.pyo",
        "pkg/__pycache__/notes.txt",
        "__PYCACHE__/MY_ENV.CPYTHON-312.PYC",
        "my_env.pyc.",
        "__pycache__ /x.txt",
    ):
        with pytest.raises(BadRequestError) as exc:
            _commit(api, "alice/env", {path: b"\x00planted bytecode"})
        message = exc.value.response.headers["X-Error-Message"]
        assert "bytecode" in message and "env repo" in message, message
        response = _raw_commit(hub.endpoint, "alice/env", _ndjson(_header(), _file(path, b"planted")))
        _assert_error(response, 400, "bytecode")
    assert api.model_info("alice/env").sha == head

    # a repo that is not an env repo is a generic Hub repo: any file
    api.create_repo("alice/generic")
    _commit(api, "alice/generic", {"__pycache__/m.cpython-312.pyc": b"\x00", "m.pyc": b"\x00"})
    # ... until it becomes an env repo: the manifest cannot join bytecode
    with pytest.raises(BadRequestError, match="bytecode"):
        _commit(api, "alice/generic", {"hub_env.json": b"{}"})
    api.create_commit(
        "alice/generic",
        [
            CommitOperationAdd(path_in_repo="hub_env.json", path_or_fileobj=b"{}"),
            CommitOperationDelete(path_in_repo="__pycache__/"),
            CommitOperationDelete(path_in_repo="m.pyc"),
        ],
        commit_message="become an env repo, bytecode removed",
    )
    assert sorted(api.list_repo_files("alice/generic")) == [".gitattributes", "hub_env.json"]


def test_a_server_can_store_bytecode_like_the_real_hub_to_test_clients(tmp_path):
    """huggingface.co stores any file: HUB_ENVS_SERVER_ALLOW_BYTECODE=1 makes the loopback server do the
    same, so the client-side defences (load_env refusing unlisted bytecode) can be tested against it."""
    with HubServer(tmp_path / "data", env={"HUB_ENVS_SERVER_ALLOW_BYTECODE": "1"}) as server:
        with hub_environment(server.endpoint, tmp_path / "home"):
            api = HfApi(endpoint=server.endpoint)
            api.create_repo("alice/env")
            _commit(api, "alice/env", {"hub_env.json": b"{}", "__pycache__/m.cpython-312.pyc": b"\x00"})
            assert "__pycache__/m.cpython-312.pyc" in api.list_repo_files("alice/env")


def test_server_and_repo_format_agree_on_the_manifest_name():
    from hub_envs.repo.format import MANIFEST_FILE
    from hub_envs.server.formats import ENV_MANIFEST

    assert ENV_MANIFEST == MANIFEST_FILE


# --- 8. (Medium, issue 30) any account could push commits onto another account's pull request -----

OWNER, BOB, CAROL = "hf_owner_token", "hf_bob_token", "hf_carol_token"


@pytest.fixture
def three_accounts(tmp_path):
    """A server whose own account (``local``) manages every repo, and two more accounts, ``bob`` and ``carol``."""
    env = {"HUB_ENVS_SERVER_USERS": f"bob:{BOB},carol:{CAROL}"}
    with HubServer(tmp_path / "accounts-data", token=OWNER, env=env) as server:
        with hub_environment(server.endpoint, tmp_path / "accounts-home", token=OWNER):
            yield server


def test_only_its_author_and_the_owner_push_to_a_pull_request(three_accounts):
    endpoint = three_accounts.endpoint
    owner, bob, carol = (HfApi(endpoint=endpoint, token=t) for t in (OWNER, BOB, CAROL))
    owner.create_repo("alice/env")
    _commit(owner, "alice/env", {"a.txt": b"a"})
    opened = bob.create_commit(
        "alice/env", [CommitOperationAdd("reproductions/x.json", b"{}")], commit_message="attest", create_pr=True
    )
    head = owner.model_info("alice/env", revision="refs/pr/1").sha
    assert opened.pr_num == 1 and head == opened.oid

    # carol, through the client (revision="refs/pr/1", as huggingface_hub documents for adding to a PR)...
    with pytest.raises(HfHubHTTPError) as exc:
        _commit(carol, "alice/env", {"reproductions/x.json": b'{"forged": true}'}, revision="refs/pr/1")
    assert exc.value.response.status_code == 403
    assert "only the pull request's author (bob) or the repo's owner" in str(exc.value)
    # ... and raw, with the ref spelled other ways, refused before the body is read
    for revision in ("refs%2Fpr%2F1", "refs/pr/1", "refs%2Fheads%2Frefs%2Fpr%2F1"):
        status, headers = _partial_request(
            endpoint, "POST", f"/api/models/alice/env/commit/{revision}", declared=64 * MiB, headers=_auth(CAROL)
        )
        assert status == 403 and "bob" in headers["x-error-message"], (revision, status)
    assert owner.model_info("alice/env", revision="refs/pr/1").sha == head
    with pytest.raises(HfHubHTTPError) as exc:  # a pull request that does not exist
        _commit(carol, "alice/env", {"x.txt": b"x"}, revision="refs/pr/7")
    assert exc.value.response.status_code == 404

    # its author and the repo's owner may; carol opens her own pull request
    by_bob = _commit(bob, "alice/env", {"b.txt": b"b"}, revision="refs/pr/1")
    by_owner = _commit(owner, "alice/env", {"c.txt": b"c"}, revision="refs/pr/1")
    assert [c.commit_id for c in owner.list_repo_commits("alice/env", revision="refs/pr/1")][:3] == [by_owner, by_bob, head]
    mine = carol.create_commit("alice/env", [CommitOperationAdd("d.txt", b"d")], commit_message="carol's", create_pr=True)
    assert mine.pr_num == 2
    _commit(carol, "alice/env", {"e.txt": b"e"}, revision="refs/pr/2")
    details = owner.get_discussion_details("alice/env", 1)
    assert [(e.type, e.author) for e in details.events if e.type == "commit"] == [
        ("commit", "bob"),
        ("commit", "bob"),
        ("commit", "local"),
    ]


# --- 9. (Low, issue 30) accounts without a server token: anonymous callers acted as the owner -------


def test_accounts_without_a_server_token_are_refused_at_start(tmp_path):
    env = {"HUB_ENVS_SERVER_USERS": f"bob:{BOB}"}
    started = []
    try:
        with pytest.raises(HubServerError) as exc:
            started.append(HubServer(tmp_path / "no-token-data", env=env))
    finally:
        for server in started:  # a server that started anyway is stopped, whatever the test found
            server.stop()
    output = str(exc.value)
    assert "hub-envs serve: Accounts are configured (HUB_ENVS_SERVER_USERS: bob)" in output
    assert "--token=" in output and "Traceback" not in output
    assert not (tmp_path / "no-token-data" / "FORMAT").exists()  # refused before the store was made
    from hub_envs.server import create_app

    with pytest.raises(ConfigError, match="would act as the owner account 'local'"):
        create_app(tmp_path / "lib-data", users={BOB: "bob"})

    # with the owner's token, an anonymous caller can neither create in bob's namespace nor delete his repo
    with HubServer(tmp_path / "token-data", token=OWNER, env=env) as server:
        bob = HfApi(endpoint=server.endpoint, token=BOB)
        bob.create_repo("bob/env")
        anonymous = HfApi(endpoint=server.endpoint, token=False)
        for attempt in (lambda: anonymous.create_repo("bob/planted"), lambda: anonymous.delete_repo("bob/env")):
            with pytest.raises(HfHubHTTPError) as exc:
                attempt()
            assert exc.value.response.status_code == 401
        assert [m.id for m in bob.list_models(author="bob")] == ["bob/env"]


# --- 10. (Low, issue 30) a pathological card stalled other clients' API requests -------------------

PATHOLOGICAL_CARD = ("![" * (256 * 1024)).encode()  # 512 KiB of nested image brackets: seconds of markdown-it


@pytest.fixture
def hub_with_card_budget(tmp_path):
    """An open server that gives a card 2 s to render (default 3 s)."""
    with HubServer(tmp_path / "card-data", env={"HUB_ENVS_SERVER_CARD_RENDER_SECONDS": "2"}) as server:
        with hub_environment(server.endpoint, tmp_path / "card-home"):
            yield server


def test_the_api_answers_while_pathological_cards_render(hub_with_card_budget):
    server = hub_with_card_budget
    api = HfApi(endpoint=server.endpoint)
    api.create_repo("mallory/card")
    api.upload_file(path_or_fileobj=PATHOLOGICAL_CARD, path_in_repo="README.md", repo_id="mallory/card")
    api.create_repo("alice/other")
    _commit(api, "alice/other", {"a.txt": b"a"})
    page = f"{server.endpoint}/mallory/card"
    html = {"Accept": "text/html"}

    # 48 browsers open the card at once: more than the server's threads (40) if each rendered it
    pages: list[requests.Response] = []
    viewers = [
        threading.Thread(target=lambda: pages.append(requests.get(page, headers=html, timeout=120)), daemon=True)
        for _ in range(48)
    ]
    for viewer in viewers:
        viewer.start()
    answered = 0
    while any(v.is_alive() for v in viewers):  # every API request answers meanwhile (a client timeout, not a speed test)
        assert requests.get(f"{server.endpoint}/api/whoami-v2", timeout=10).status_code == 200
        assert api.model_info("alice/other", timeout=10).sha
        answered += 1
        time.sleep(0.05)
    for viewer in viewers:
        viewer.join()
    assert answered >= 3 and len(pages) == 48 and all(p.status_code == 200 for p in pages)

    # the card is shown as its text, escaped, with a note saying why; the next view comes from the cache
    again = requests.get(page, headers=html, timeout=TIMEOUT)
    assert "This card is shown as plain text: it takes longer than 2 s to render." in again.text
    assert '<pre class="card-plain">![![![' in again.text and "<img" not in again.text
    assert "takes longer than 2 s to render" in server.output()
    # other cards still render (a fresh renderer replaced the one stopped past the budget)
    api.upload_file(path_or_fileobj=b"# Fine\n\n*emphasis*\n", path_in_repo="README.md", repo_id="alice/other")
    fine = requests.get(f"{server.endpoint}/alice/other", headers=html, timeout=TIMEOUT)
    assert "<h1>Fine</h1>" in fine.text and "<em>emphasis</em>" in fine.text and "plain text" not in fine.text


# --- 11. (Low, issue 30) 1 GiB NDJSON lines; half-open connections held forever -------------------


def test_commit_lines_are_capped_at_what_huggingface_hub_sends(hub):
    api = hub.api
    api.create_repo("alice/env")
    head = api.model_info("alice/env").sha
    # the largest file the client sends inline: 10 MiB of text (over it, /preupload sends it through LFS)
    largest_inline = b"0123456789abcdef" * (640 * 1024)
    sha = _commit(api, "alice/env", {"largest.txt": largest_inline, "larger.txt": largest_inline + b"!"})
    info = {s.rfilename: s for s in api.model_info("alice/env", revision=sha, files_metadata=True).siblings}
    assert info["largest.txt"].lfs is None and info["larger.txt"].lfs is not None
    assert Path(hf_hub_download("alice/env", "largest.txt", revision=sha)).read_bytes() == largest_inline
    # a client that ignores /preupload and sends 24 MiB inline: 413 naming the limit, nothing committed
    response = _raw_commit(hub.endpoint, "alice/env", _ndjson(_header(), _file("big.txt", b"x" * (24 * MiB))))
    _assert_error(response, 413, "16 MiB", "HUB_ENVS_SERVER_MAX_LINE_MB", "Git LFS")
    assert api.model_info("alice/env").sha == sha != head


def _half_open(endpoint: str, sent: bytes) -> socket.socket:
    host, port = endpoint.removeprefix("http://").split(":")
    sock = socket.create_connection((host, int(port)), timeout=TIMEOUT)
    if sent:
        sock.sendall(sent)
    return sock


def _closed_by_server(sock: socket.socket) -> bytes:
    """What the server sends before closing ``sock`` (socket.timeout if it keeps it open past TIMEOUT)."""
    received = b""
    while True:
        chunk = sock.recv(4096)
        if not chunk:
            return received
        received += chunk


def test_half_open_connections_are_dropped_and_connections_capped(tmp_path):
    env = {"HUB_ENVS_SERVER_HEADER_TIMEOUT": "4", "HUB_ENVS_SERVER_MAX_CONNECTIONS": "200"}
    with HubServer(tmp_path / "conn-data", env=env) as server, hub_environment(server.endpoint, tmp_path / "conn-home"):
        api = HfApi(endpoint=server.endpoint)
        api.create_repo("alice/env")
        head = b"GET /api/whoami-v2 HTTP/1.1\r\nHost: x\r\n"  # a request head never finished
        silent = [_half_open(server.endpoint, b"") for _ in range(80)]
        partial = [_half_open(server.endpoint, head) for _ in range(80)]
        assert api.model_info("alice/env").sha  # served meanwhile
        # a slow loris: one more header byte every 0.2 s does not extend the deadline
        loris = _half_open(server.endpoint, head)
        with pytest.raises(OSError):  # BrokenPipe / ConnectionReset once the server closed it
            for _ in range(int(TIMEOUT / 0.2)):
                loris.sendall(b"X")
                time.sleep(0.2)
        # a keep-alive connection: one request answered, then the next head begun and never finished
        reused = _half_open(server.endpoint, head + b"\r\n")
        first = b""
        while b"\r\n\r\n" not in first:
            first += reused.recv(4096)
        head_part, _, body = first.partition(b"\r\n\r\n")
        length = int(next(h.split(b":")[1] for h in head_part.split(b"\r\n") if h.lower().startswith(b"content-length:")))
        while len(body) < length:
            body += reused.recv(4096)
        assert first.startswith(b"HTTP/1.1 200 ") and json.loads(body)["name"] == "local", first[:100]
        reused.sendall(head)
        for sock in [*silent, *partial, reused]:
            answer = _closed_by_server(sock)  # closed by the server, with a 408
            assert answer.startswith(b"HTTP/1.1 408 "), answer[:100]
            sock.close()
        loris.close()
        assert api.model_info("alice/env").sha

        # past the connection cap, requests get a prompt 503, and are served again once connections are dropped
        held = [_half_open(server.endpoint, b"") for _ in range(200)]
        response = requests.get(f"{server.endpoint}/api/whoami-v2", timeout=TIMEOUT)
        assert response.status_code == 503
        for sock in held:
            _closed_by_server(sock)
            sock.close()
        assert requests.get(f"{server.endpoint}/api/whoami-v2", timeout=TIMEOUT).status_code == 200


# === attacks that already failed: keep them failing =============================================


def test_path_traversal_in_every_encoding_is_refused(hub, tmp_path):
    api, endpoint = hub.api, hub.endpoint
    api.create_repo("alice/env")
    head = _commit(api, "alice/env", {"ok.txt": b"ok", "d/in.txt": b"in"})
    store_markers = (b"hub-envs-store", b'"createdAt"', b'"branches"', b"root:")
    escapes = [
        "%2e%2e/%2e%2e/%2e%2e/FORMAT",
        "%2E%2E%2F%2E%2E%2F%2E%2E%2FFORMAT",
        "..%2f..%2f..%2frepo.json",
        "d/..%2f..%2f..%2f..%2fFORMAT",
        "..%5c..%5crepo.json",
        "%5c..%5crefs.json",
        "%2fetc%2fpasswd",
        "%2F..%2F..%2FFORMAT",
        "C:%5cWindows",
        "d/.%2fin.txt",
        "d//in.txt",
        "ok.txt%00.png",
    ]
    for escape in escapes:
        for url in (f"/alice/env/resolve/main/{escape}", f"/api/models/alice/env/tree/main/{escape}"):
            for method in ("GET", "HEAD"):
                response = requests.request(method, endpoint + url, timeout=TIMEOUT)
                # the tree route reads "/x" as "x" (the client may send a leading "/"): not found, then
                lenient = "/tree/" in url and response.headers.get("X-Error-Code") == "EntryNotFound"
                assert response.status_code == 400 or lenient, (method, url, response.status_code)
                assert not any(m in response.content for m in store_markers), url
    # double-encoded: decoded once, it is a literal (odd) file name, never a traversal
    for url in ("/alice/env/resolve/main/%252e%252e/%252e%252e/FORMAT", "/api/models/alice/env/tree/main/%252e%252e"):
        response = requests.get(endpoint + url, timeout=TIMEOUT)
        assert response.status_code == 404 and response.headers["X-Error-Code"] == "EntryNotFound", url
    # literal dot segments, which `requests` would normalize away before sending
    host, port = endpoint.removeprefix("http://").split(":")
    for raw in (
        "/alice/env/resolve/main/../../../FORMAT",
        "/alice/env/resolve/main/d/../../../../repo.json",
        "/api/models/alice/env/tree/main/../..",
        "/alice/env/resolve/main/..\\..\\repo.json",
    ):
        conn = http.client.HTTPConnection(host, int(port), timeout=TIMEOUT)
        conn.request("GET", raw)
        response = conn.getresponse()
        body = response.read()
        conn.close()
        assert response.status == 400 and not any(m in body for m in store_markers), raw
    # in bodies: paths-info and commits
    for path in (
        "../FORMAT",
        "../../repo.json",
        "a/../../x",
        "/etc/passwd",
        "a\\..\\x",
        "..\\x",
        ".",
        "./a",
        ".git/config",
        "%2e%2e/x",
        "C:\\x",
    ):
        response = requests.post(f"{endpoint}/api/models/alice/env/paths-info/main", json={"paths": [path]}, timeout=TIMEOUT)
        if "%" in path or path.startswith("/"):  # a literal name; "/x" read as "x": simply not found
            assert response.status_code == 200 and response.json() == [], (path, response.status_code)
        else:
            assert response.status_code == 400, (path, response.status_code)
        response = _raw_commit(endpoint, "alice/env", _ndjson(_header(), _file(path, b"pwned")))
        if "%" in path:
            assert response.status_code == 200  # a file literally named "%2e%2e/x": allowed, inside the repo
        else:
            _assert_error(response, 400, "Invalid path")
        for key in ("deletedFile", "deletedFolder") if "%" not in path else ():
            response = _raw_commit(endpoint, "alice/env", _ndjson(_header(), {"key": key, "value": {"path": path}}))
            assert 400 <= response.status_code < 500, (key, path, response.status_code)
    assert (hub.root / "FORMAT").read_text().startswith("hub-envs-store")
    assert not list(tmp_path.rglob("pwned")) and not [p for p in tmp_path.rglob("*") if p.name in ("x", "passwd")]
    files = api.list_repo_files("alice/env")
    assert set(files) == {".gitattributes", "ok.txt", "d/in.txt", "%2e%2e/x"}
    assert api.model_info("alice/env").sha != head  # only the literal "%2e%2e/x" was committed


def test_every_write_route_needs_the_token(hub_with_token):
    hub = hub_with_token
    hub.api.create_repo("alice/env")
    hub.api.create_tag("alice/env", tag="v1")
    before = (hub.api.model_info("alice/env").sha, hub.api.list_repo_refs("alice/env"))
    bodies = {
        "/api/repos/create": {"name": "x", "organization": "alice"},
        "/api/repos/delete": {"name": "env", "organization": "alice"},
        "/api/validate-yaml": {"content": "---\na: 1\n---\n"},
    }
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": "Basic YWxpY2U6cHc="}, {"Authorization": "Bearer "}):
        for method, path in _write_routes("alice/env"):
            if path.endswith("/commit/main"):
                response = requests.post(
                    hub.endpoint + path, data=_ndjson(_header(), _file("x.txt", b"x")), headers=headers, timeout=TIMEOUT
                )
            else:
                body = bodies.get(path, {"tag": "v2", "files": [], "private": True})
                response = requests.request(method, hub.endpoint + path, json=body, headers=headers, timeout=TIMEOUT)
            assert response.status_code == 401, (headers, method, path, response.status_code)
    anonymous = HfApi(endpoint=hub.endpoint, token=False)
    for write in (
        lambda: anonymous.create_repo("alice/new"),
        lambda: anonymous.delete_repo("alice/env"),
        lambda: _commit(anonymous, "alice/env", {"x.txt": b"x"}),
        lambda: anonymous.create_branch("alice/env", branch="dev"),
        lambda: anonymous.delete_tag("alice/env", tag="v1"),
        lambda: anonymous.update_repo_settings("alice/env", private=True),
    ):
        with pytest.raises(HfHubHTTPError) as exc:
            write()
        assert exc.value.response.status_code == 401
    assert (hub.api.model_info("alice/env").sha, hub.api.list_repo_refs("alice/env")) == before
    assert not hub.api.repo_exists("alice/x") and not hub.api.repo_exists("alice/new")
    assert hub.api.model_info("alice/env").private is False


def test_private_repos_look_missing_without_the_token(hub_with_token):
    hub = hub_with_token
    hub.api.create_repo("alice/secret", private=True)
    sha = _commit(hub.api, "alice/secret", {"s.txt": b"s"})
    hub.api.create_tag("alice/secret", tag="v1")
    reads = [
        ("GET", "/api/models/alice/{name}"),
        ("GET", "/api/models/alice/{name}/revision/main"),
        ("GET", "/api/models/alice/{name}/tree/main"),
        ("GET", "/api/models/alice/{name}/refs"),
        ("GET", "/api/models/alice/{name}/commits/main"),
        ("POST", "/api/models/alice/{name}/paths-info/main"),
        ("GET", "/alice/{name}/resolve/main/s.txt"),
        ("HEAD", "/alice/{name}/resolve/main/s.txt"),
        ("GET", f"/alice/{{name}}/resolve/{sha}/s.txt"),
        ("GET", "/alice/{name}/resolve/v1/s.txt"),
    ]
    for method, template in reads:
        private = requests.request(
            method, hub.endpoint + template.format(name="secret"), json={"paths": ["s.txt"]}, timeout=TIMEOUT
        )
        missing = requests.request(
            method, hub.endpoint + template.format(name="nothing"), json={"paths": ["s.txt"]}, timeout=TIMEOUT
        )
        # as on the Hub: an anonymous caller cannot tell a private repo from a missing one (401, RepoNotFound)
        assert private.status_code == missing.status_code == 401, (template, private.status_code, missing.status_code)
        assert private.headers.get("X-Error-Code") == missing.headers.get("X-Error-Code") == "RepoNotFound"
        assert b"s.txt" not in private.content and sha.encode() not in private.content
        authed = requests.request(
            method,
            hub.endpoint + template.format(name="secret"),
            json={"paths": ["s.txt"]},
            headers=_auth(hub.token),
            timeout=TIMEOUT,
        )
        assert authed.status_code == 200, (template, authed.status_code)
    anonymous = HfApi(endpoint=hub.endpoint, token=False)
    with pytest.raises(RepositoryNotFoundError):
        anonymous.model_info("alice/secret")
    assert "alice/secret" not in {m["id"] for m in requests.get(f"{hub.endpoint}/api/models", timeout=TIMEOUT).json()}
    assert "alice/secret" in {m.id for m in hub.api.list_models()}


def test_racing_commits_with_the_same_parent_leave_one_winner(hub):
    api = hub.api
    api.create_repo("alice/env")
    parent = api.model_info("alice/env").sha
    barrier = threading.Barrier(2)
    results: dict[int, object] = {}

    def worker(i: int) -> None:
        barrier.wait()
        try:
            results[i] = _commit(api, "alice/env", {f"f{i}.txt": b"x" * (100 + i)}, parent_commit=parent)
        except HfHubHTTPError as err:
            results[i] = err

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    winners = [r for r in results.values() if isinstance(r, str)]
    losers = [r for r in results.values() if isinstance(r, HfHubHTTPError)]
    assert len(winners) == 1 and len(losers) == 1 and losers[0].response.status_code == 412
    assert [c.commit_id for c in api.list_repo_commits("alice/env")] == [winners[0], parent]
    assert len(api.list_repo_files("alice/env")) == 2
