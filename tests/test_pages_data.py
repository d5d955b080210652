"""The embedded Hub's pages for what people look at (issue 34): the dataset viewer (``/{user}/{repo}/episodes``,
env repos and dataset repos), the pull request pages (``/{user}/{repo}/discussions[/N]`` for a browser), the
reproductions matrix on the repo page, and the page flaws (favicon, empty table headers, wrapped numbers, a
folder's size). First over plain HTTP against a real ``hub-envs serve`` holding envs pushed with push_env, then
in a real browser (Debian's chromium, Playwright: the ``browser`` fixture of test_pages.py)."""

from __future__ import annotations

import io
import json
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import requests
from conftest import Hub, _start_hub
from helpers import TINY, copy_env
from huggingface_hub import CommitOperationAdd, HfApi, snapshot_download
from test_pages import HTML, browser  # noqa: F401 - the browser fixture, reused

from hub_envs import push_env
from hub_envs.cli import main as cli_main
from hub_envs.dataset.reader import read_episode_frames, read_episode_meta
from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset

ENVS = Path(__file__).resolve().parent.parent / "envs"
OWNER, BOB = "hf_owner_pages_token", "hf_bob_pages_token"
TINY_REPO, REACH_REPO = "alice/tiny-data", "alice/reach-data"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Iterator[Hub]:
    """A server whose own account (``local``, the default ``HF_TOKEN``) manages every repo, and ``bob``."""
    yield from _start_hub(tmp_path_factory.mktemp("hub-data-pages"), token=OWNER, env={"HUB_ENVS_SERVER_USERS": f"bob:{BOB}"})


@pytest.fixture(scope="module")
def tiny(site):
    return push_env(TINY, TINY_REPO, episodes=3, progress=False)


@pytest.fixture(scope="module")
def reach(site, tmp_path_factory):
    """reach pushed with its camera as video (AV1, LeRobot's encoder): 2 episodes of 12 steps."""
    folder = copy_env(
        tmp_path_factory.mktemp("reach"),
        ENVS / "reach",
        "reach",
        edits={"config.py": lambda s: s.replace("episode_length: int = 100", "episode_length: int = 12")},
    )
    return push_env(folder, REACH_REPO, episodes=2, progress=False)


def _get(site: Hub, path: str, html: bool = False, **kw) -> requests.Response:
    headers = {"Authorization": f"Bearer {OWNER}", **(HTML if html else {})}
    return requests.get(site.endpoint + path, headers=headers, timeout=60, **kw)


def _local_dataset(site: Hub, repo_id: str, sha: str, repo_type: str = "model") -> Path:
    folder = Path(snapshot_download(repo_id, revision=sha, repo_type=repo_type, endpoint=site.endpoint, token=OWNER))
    return folder / "dataset" if repo_type == "model" else folder


def _text(html: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html)).replace("&#39;", "'").replace("&#34;", '"')


# --- 1. the dataset viewer, over HTTP -------------------------------------------------------------


def test_the_episodes_page_lists_each_episode_with_its_task_success_and_return(site, tiny):
    page = _get(site, f"/{TINY_REPO}")
    assert f'href="/{TINY_REPO}/episodes?rev={tiny.sha}">Episodes</a>' in page.text  # reached from the env's page
    r = _get(site, f"/{TINY_REPO}/episodes")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    text = _text(r.text)
    assert "3 episodes" in text and "LeRobot v3.0 dataset in dataset/" in text
    meta = read_episode_meta(_local_dataset(site, TINY_REPO, tiny.sha))
    for m in meta:
        frames = read_episode_frames(_local_dataset(site, TINY_REPO, tiny.sha), m["episode_index"])
        ret = float(frames["next.reward"].astype(np.float64).sum())
        row = re.search(rf"episode {m['episode_index']} (\d+) [\d.]+ s (.+?) (✓ success|✗) (-?[\d.]+) {m['seed']}", text)
        assert row, text
        assert int(row.group(1)) == m["length"] and row.group(2) == m["tasks"][0]
        assert (row.group(3) == "✓ success") == bool(frames["next.success"].any())
        assert float(row.group(4)) == pytest.approx(ret, abs=2e-3)
        assert f'href="/{TINY_REPO}/episodes/{m["episode_index"]}?rev={tiny.sha}"' in r.text


def test_an_episodes_data_is_its_rows_of_the_dataset(site, tiny):
    root = _local_dataset(site, TINY_REPO, tiny.sha)
    frames = read_episode_frames(root, 1)
    r = _get(site, f"/{TINY_REPO}/episodes/1/data.json?rev={tiny.sha}")
    assert r.status_code == 200 and r.headers["content-type"] == "application/json"
    assert "immutable" in r.headers["Cache-Control"]  # pinned to a commit
    data = r.json()
    series = {s["key"]: s for s in data["keys"]}
    assert list(series)[:3] == ["observation.state", "action", "next.reward"]  # state, action, reward first
    state = np.array(series["observation.state"]["values"]).T
    assert state.shape == frames["observation.state"].shape
    np.testing.assert_array_equal(state.astype(np.float32), frames["observation.state"])
    np.testing.assert_array_equal(np.array(series["action"]["values"]).T.astype(np.float32), frames["action"])
    np.testing.assert_array_equal(np.array(data["timestamps"], dtype=np.float32), frames["timestamp"].reshape(-1))
    assert data["length"] == len(frames["index"]) and data["fps"] == 20

    page = _get(site, f"/{TINY_REPO}/episodes/1")
    assert page.status_code == 200
    assert f'data-data="/{TINY_REPO}/episodes/1/data.json?rev={tiny.sha}"' in page.text
    assert '<canvas data-key="observation.state"' in page.text and '<script src="/_hub/static/viewer.js" defer>' in page.text
    assert "<script>" not in page.text  # CSP: no inline script
    text = _text(page.text)
    meta = read_episode_meta(root)[1]
    assert "Episode 1 of 3" in text and f"task {meta['tasks'][0]} success" in text
    assert f"length {meta['length']} steps, {meta['length'] / 20:.2f} s at 20.0 fps reset seed 1" in text


def test_the_viewer_reads_a_dataset_repo_with_many_episodes_across_files(site, tmp_path):
    """A dataset-type repo with the LeRobot dataset at its root (as push_env also publishes it), 250 episodes
    written into many data files (a tiny file size): the list pages through them, and an episode in the last
    file is its own rows. (1000 episodes: benchmarks/bench_pages.py.)"""
    root = tmp_path / "ds"
    features = {
        "observation.state": {"dtype": "float32", "shape": [3], "names": ["a", "b", "c"]},
        "action": {"dtype": "float32", "shape": [1], "names": ["u"]},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "next.success": {"dtype": "bool", "shape": [1], "names": None},
    }
    rng = np.random.default_rng(0)

    def episodes():
        for i in range(250):
            n = 3 + i % 5
            yield EpisodeFrames(
                i,
                seed=i,
                frames={
                    "observation.state": rng.normal(size=(n, 3)).astype(np.float32),
                    "action": rng.uniform(-1, 1, (n, 1)).astype(np.float32),
                    "next.reward": np.full((n, 1), -i, np.float32),
                    "next.success": (np.arange(n) == n - 1).reshape(n, 1) & (i % 2 == 0),
                },
            )

    write_lerobot_dataset(root, repo_id="alice/many", fps=10, features=features, episodes=episodes(), task="many",
                          progress=False, data_files_size_in_mb=0.01)  # fmt: skip
    files = sorted(p.name for p in (root / "data" / "chunk-000").iterdir())
    assert len(files) > 5
    api: HfApi = site.api
    api.create_repo("alice/many", repo_type="dataset")
    sha = api.upload_folder(repo_id="alice/many", repo_type="dataset", folder_path=str(root), commit_message="1000 episodes").oid

    listing = _get(site, "/datasets/alice/many/episodes?p=2")
    assert listing.status_code == 200
    text = _text(listing.text)
    assert "250 episodes" in text and "page 3 of 3" in text and "episode 249 " in text and "episode 199 " not in text
    assert "LeRobot v3.0 dataset in /" in text
    last = read_episode_frames(root, 249)
    data = _get(site, f"/datasets/alice/many/episodes/249/data.json?rev={sha}").json()
    state = np.array(data["keys"][0]["values"]).T.astype(np.float32)
    np.testing.assert_array_equal(state, last["observation.state"])
    assert data["keys"][0]["names"] == ["a", "b", "c"]
    assert "Episodes</a>" in _get(site, "/datasets/alice/many").text


def test_an_image_dataset_serves_each_frame_as_the_png_it_stores(site, tmp_path):
    import pyarrow.parquet as pq

    root = tmp_path / "img"
    features = {
        "observation.image": {"dtype": "image", "shape": [8, 8, 3], "names": ["height", "width", "channels"]},
        "action": {"dtype": "float32", "shape": [1], "names": ["u"]},
    }
    rng = np.random.default_rng(1)
    eps = [
        EpisodeFrames(i, seed=i, frames={"observation.image": rng.integers(0, 255, (4, 8, 8, 3), np.uint8),
                                         "action": np.zeros((4, 1), np.float32)})
        for i in range(2)
    ]  # fmt: skip
    write_lerobot_dataset(root, repo_id="alice/img", fps=5, features=features, episodes=eps, task="look", progress=False)
    api: HfApi = site.api
    api.create_repo("alice/img", repo_type="dataset")
    api.upload_folder(repo_id="alice/img", repo_type="dataset", folder_path=str(root), commit_message="images")
    table = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet")
    stored = [
        row["bytes"]
        for row, ep in zip(table.column("observation.image").to_pylist(), table.column("episode_index").to_pylist())
        if ep == 1
    ]
    page = _get(site, "/datasets/alice/img/episodes/1").text
    assert 'class="episode-frame" data-key="observation.image"' in page
    for step in (0, 3):
        r = _get(site, f"/datasets/alice/img/episodes/1/frames/observation.image/{step}.png")
        assert r.status_code == 200 and r.headers["content-type"] == "image/png" and r.content == stored[step]
    from PIL import Image

    decoded = np.asarray(
        Image.open(io.BytesIO(_get(site, "/datasets/alice/img/episodes/1/frames/observation.image/2.png").content))
    )
    np.testing.assert_array_equal(decoded, eps[1].frames["observation.image"][2])
    missing = _get(site, "/datasets/alice/img/episodes/1/frames/observation.image/4.png")
    assert missing.status_code == 422 and "no frame 4" in missing.text


@pytest.mark.parametrize(
    ("info", "status", "said"),
    [
        (
            {"codebase_version": "v3.0", "fps": 10, "features": {}, "data_path": "{chunk_index.__class__}/x.parquet"},
            422,
            "data_path uses",
        ),
        ({"codebase_version": "v2.1", "features": {}}, 422, "the viewer reads v3.0 datasets"),
        ("not json", 422, "not valid JSON"),
    ],
)
def test_a_hostile_or_foreign_dataset_gets_a_page_saying_why(site, info, status, said):
    name = f"alice/odd-{abs(hash(str(info))) % 10**6}"
    api: HfApi = site.api
    api.create_repo(name, repo_type="dataset")
    meta = json.dumps(info).encode() if isinstance(info, dict) else info.encode()
    episodes = io.BytesIO()
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = {"episode_index": [0], "length": [1], "data/chunk_index": [0], "data/file_index": [0],
            "dataset_from_index": [0], "dataset_to_index": [1]}  # fmt: skip
    pq.write_table(pa.table(cols), episodes)
    api.create_commit(
        name,
        [
            CommitOperationAdd("meta/info.json", meta),
            CommitOperationAdd("meta/episodes/chunk-000/file-000.parquet", episodes.getvalue()),
        ],
        commit_message="odd",
        repo_type="dataset",
    )
    listing = _get(site, f"/datasets/{name}/episodes")
    r = _get(site, f"/datasets/{name}/episodes/0/data.json") if listing.status_code == 200 else listing
    assert r.status_code == status and said in _text(r.text), r.text
    assert _get(site, f"/datasets/{name}").status_code == 200  # the repo page still answers


def test_a_repo_without_a_dataset_says_so(site, tiny):
    site.api.create_repo("alice/plain")
    r = _get(site, "/alice/plain/episodes")
    assert r.status_code == 404 and "holds no LeRobot dataset" in r.text and "Episodes</a>" not in _get(site, "/alice/plain").text
    assert _get(site, f"/{TINY_REPO}/episodes/7").status_code == 404
    assert _get(site, f"/{TINY_REPO}/episodes/x").status_code == 400


# --- 2 and 3. pull requests and the reproductions matrix -----------------------------------------------------


@pytest.fixture(scope="module")
def attested(site, tiny, tmp_path_factory, monkeypatch_module):
    """bob reproduces the tiny env and attests it, signed (``hub-envs reproduce --attest=true --sign_key=...``):
    what it prints, and the pull request's number."""
    if shutil.which("ssh-keygen") is None:
        pytest.skip("ssh-keygen is needed to sign an attestation")
    tmp = tmp_path_factory.mktemp("attest")
    key = tmp / "bob_key"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", "bob@example.org", "-f", str(key)], check=True)
    monkeypatch_module.setenv("HF_TOKEN", BOB)
    out = io.StringIO()
    import contextlib

    with contextlib.redirect_stdout(out):
        code = cli_main(
            ["reproduce", f"--repo_id={TINY_REPO}", f"--revision={tiny.sha}", "--trust_remote_code=true", "--workers=1",
             f"--out={tmp / 'out'}", "--attest=true", f"--sign_key={key}"]
        )  # fmt: skip
    monkeypatch_module.setenv("HF_TOKEN", OWNER)
    printed = out.getvalue()
    assert code == 0, printed
    url = re.search(r"(http://\S+/discussions/(\d+))", printed)
    assert url, printed
    return url.group(1), int(url.group(2))


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def test_the_url_reproduce_prints_opens_the_pull_request_page(site, tiny, attested):
    url, num = attested
    r = requests.get(url, headers={**HTML, "Authorization": f"Bearer {OWNER}"}, timeout=60)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    text = _text(r.text)
    assert f"#{num}" in text and "open bob wants to merge" in text and "Reproduction attestation: REPRODUCED" in text
    assert "verdict ✓ REPRODUCED" in text and f"env revision {tiny.sha}" in text
    assert "signature present, not verified here" in text
    assert "attested by bob (the pull request's author" in text
    assert f"HfApi().merge_pull_request('{TINY_REPO}', {num})" in text
    assert "The account 'alice' (the repo's namespace) or the server's own account 'local' may merge it" in text
    assert re.search(r"added reproductions/\d{4}-\d{2}-\d{2}-[0-9a-f-]+\.json ", text) and ".json.sig" in text
    assert '<tr class="add"><td>+  &#34;verdict&#34;: &#34;REPRODUCED&#34;</td></tr>' in r.text  # the record's lines, as a diff
    # the API on those paths is untouched: JSON for huggingface_hub, on /api/ whatever the Accept header
    assert requests.get(url, timeout=30).headers["content-type"] == "application/json"
    api_url = url.replace(f"/{TINY_REPO}/", f"/api/models/{TINY_REPO}/")
    detail = requests.get(api_url, headers={**HTML, "Authorization": f"Bearer {OWNER}"}, timeout=30)
    assert detail.headers["content-type"] == "application/json" and detail.json()["author"]["name"] == "bob"
    listing = _get(site, f"/{TINY_REPO}/discussions", html=True)
    assert f'href="/{TINY_REPO}/discussions/{num}">Reproduction attestation: REPRODUCED' in listing.text


def test_a_pull_request_page_shows_a_text_diff_and_sizes_for_binary_and_lfs_files(site, tiny):
    bob = HfApi(endpoint=site.endpoint, token=BOB)
    card = (Path(snapshot_download(TINY_REPO, revision=tiny.sha, endpoint=site.endpoint, token=OWNER)) / "README.md").read_text()
    edited = card.replace("# tiny-env", "# tiny-env (edited by bob)", 1)
    opened = bob.create_commit(
        TINY_REPO,
        [
            CommitOperationAdd("README.md", edited.encode()),
            CommitOperationAdd("media/extra.bin", bytes(range(256))),
            CommitOperationAdd("dataset/extra.parquet", b"PAR1" + b"\0" * 100),
        ],
        commit_message="bob's edits",
        create_pr=True,
    )
    r = _get(site, f"/{TINY_REPO}/discussions/{opened.pr_num}", html=True)
    assert r.status_code == 200
    text = _text(r.text)
    assert '<tr class="del"><td>-# tiny-env' in r.text and '<tr class="add"><td>+# tiny-env (edited by bob)' in r.text
    assert "added media/extra.bin 256 B LFS stored with Git LFS: sizes only" in text  # binary: through LFS
    assert "added dataset/extra.parquet 104 B LFS stored with Git LFS: sizes only" in text  # an LFS pattern
    assert "Reproduction attestation" not in text  # no record in this one
    bob.change_discussion_status(TINY_REPO, opened.pr_num, "closed")
    assert "Closed without merging." in _get(site, f"/{TINY_REPO}/discussions/{opened.pr_num}", html=True).text


def test_in_a_browser_the_url_reproduce_prints_opens_the_pr_page(site, tiny, attested, browser):  # noqa: F811
    url, num = attested
    context = browser.new_context(
        extra_http_headers={"Authorization": f"Bearer {OWNER}"}, permissions=["clipboard-read", "clipboard-write"]
    )
    try:
        page = context.new_page()
        problems = _watch(page)
        page.goto(url)  # the URL `reproduce --attest=true` printed
        assert page.locator("h2.pr-title").inner_text().startswith("Reproduction attestation: REPRODUCED")
        assert "signature present, not verified here" in page.locator(".attestation .signature").inner_text()
        page.click("button[data-copy=merge-call]")
        assert page.evaluate("navigator.clipboard.readText()") == f"HfApi().merge_pull_request('{TINY_REPO}', {num})"
        page.click(f"a:text-is('{TINY_REPO}')")  # the repo page: its matrix holds the open attestation
        page.wait_for_url(f"{site.endpoint}/{TINY_REPO}")
        cell = page.locator(".repro-matrix a.cell")
        assert cell.count() == 1 and cell.inner_text().split() == ["✓", "signed", "by", "bob", "PR", f"#{num},", "open"]
        cell.click()
        page.wait_for_url(url)
        assert problems == [], problems
    finally:
        context.close()


@pytest.fixture(scope="module")
def matrix_state(site, tiny, attested):
    """The owner merges bob's signed attestation; bob opens a second one by hand: unsigned, NOT REPRODUCED on
    another stack, declaring it is alice's. (After the tests that want bob's pull request open.)"""
    url, num = attested
    api: HfApi = site.api
    api.merge_pull_request(TINY_REPO, num)
    record = {
        "kind": "hub-envs reproduction attestation",
        "format_version": 1,
        "sha": tiny.sha,
        "verdict": "NOT REPRODUCED",
        "reproduced": False,
        "stack_digest": "0123456789ab",
        "stack": {"python": "3.11.7", "packages": {"lerobot": "0.4.4"}, "platform": "Linux-6.1", "machine": "x86_64"},
        "created_at": "2026-01-02T00:00:00Z",
        "attested_by": "alice",
    }
    bob = HfApi(endpoint=site.endpoint, token=BOB)
    second = bob.create_commit(
        TINY_REPO,
        [CommitOperationAdd("reproductions/2026-01-02-0123456789ab.json", json.dumps(record).encode())],
        commit_message="another attestation",
        create_pr=True,
    )
    return api.model_info(TINY_REPO).sha, num, second.pr_num


def test_the_repo_page_shows_the_matrix_with_who_attested_and_signatures(site, tiny, matrix_state):
    merged, num, second_num = matrix_state
    r = _get(site, f"/{TINY_REPO}")
    html = r.text
    assert 'id="reproductions"' in html
    matrix = _text(html[html.index('id="reproductions"') : html.index("</section>", html.index('id="reproductions"'))])
    assert f"{tiny.sha[:12]}" in matrix and "0123456789ab python 3.11.7, lerobot 0.4.4 on Linux x86_64" in matrix
    assert f"✓ signed by bob PR #{num}" in matrix  # merged, signed, published by bob
    assert f"✗ unsigned by bob PR #{second_num}, open" in matrix  # the record's "alice" is not trusted
    merged_path = re.search(r'href="(/alice/tiny-data/blob/[0-9a-f]{40}/reproductions/[^"]+\.json)"', html).group(1)
    assert merged in merged_path and _get(site, merged_path).status_code == 200  # each cell links to its record
    assert f'href="/{TINY_REPO}/discussions/{second_num}"' in html
    pr_page = _text(_get(site, f"/{TINY_REPO}/discussions/{second_num}", html=True).text)
    assert "signature unsigned" in pr_page and "the file declares alice, which is not checked" in pr_page


# --- 4. page flaws ---------------------------------------------------------------------------------------


def test_the_favicon_is_served(site):
    icon = _get(site, "/favicon.ico")
    assert icon.status_code == 200 and icon.headers["content-type"] == "image/x-icon" and icon.content[:4] == b"\0\0\1\0"
    svg = _get(site, "/_hub/static/favicon.svg")
    assert svg.status_code == 200 and svg.headers["content-type"] == "image/svg+xml" and svg.text.startswith("<svg")
    assert '<link rel="icon" href="/_hub/static/favicon.svg" type="image/svg+xml">' in _get(site, "/", html=True).text


def test_a_table_whose_header_cells_are_empty_has_no_header_row(site, tiny):
    page = _get(site, f"/{TINY_REPO}/tree/{tiny.sha}").text
    assert (
        "| | |"
        in (Path(snapshot_download(TINY_REPO, revision=tiny.sha, endpoint=site.endpoint, token=OWNER)) / "README.md").read_text()
    )
    assert "<th></th>" not in page  # the card's "| | |" tables: no empty header row...
    assert re.search(
        r"<table class=\"card-table\">\s*<tbody>\s*<tr>\s*<td>repo</td>\s*<td><code>alice/tiny-data</code></td>", page
    )
    assert "<th>feature</th>" in page  # ... while a table with a header keeps it


def test_a_folders_header_gives_the_folders_size(site, tiny):
    root = Path(snapshot_download(TINY_REPO, revision=tiny.sha, endpoint=site.endpoint, token=OWNER))
    dataset = [p for p in (root / "dataset").rglob("*") if p.is_file()]
    size = sum(p.stat().st_size for p in dataset)
    folder = _text(_get(site, f"/{TINY_REPO}/tree/{tiny.sha}/dataset").text)
    from hub_envs.server.pages import format_size

    assert f"Files / dataset · {len(dataset)} files, {format_size(size)}" in folder
    whole = [p for p in root.rglob("*") if p.is_file() and ".cache" not in p.parts]
    assert f"Files · {len(whole)} files" in _text(_get(site, f"/{TINY_REPO}/tree/{tiny.sha}").text)


# --- in a browser ------------------------------------------------------------------------------------------


def _watch(page) -> list[str]:
    problems: list[str] = []
    page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type in ("error", "warning") else None)
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    page.on("response", lambda r: problems.append(f"{r.status} {r.url}") if r.status >= 400 else None)
    return problems


def test_in_a_browser_the_viewer_plays_an_episode_of_reachs_video_and_plots_its_state(site, reach, browser):  # noqa: F811
    context = browser.new_context(
        extra_http_headers={"Authorization": f"Bearer {OWNER}"}, viewport={"width": 1200, "height": 900}
    )
    try:
        page = context.new_page()
        problems = _watch(page)
        page.goto(f"{site.endpoint}/{REACH_REPO}")
        page.click("nav.repo-nav a:text-is('Episodes')")
        page.wait_for_url(re.compile(r"/episodes\?rev="))
        page.click("a:text-is('episode 1')")
        page.wait_for_function("() => document.querySelector('.viewer').dataset.ready === 'true'")
        video = page.locator("video.episode-video")
        assert video.count() == 1
        page.wait_for_function("() => document.querySelector('video.episode-video').readyState >= 2")
        assert video.evaluate("v => v.videoWidth") == 96  # the AV1 stream decodes
        start, stop = float(video.get_attribute("data-from")), float(video.get_attribute("data-to"))
        assert stop - start == pytest.approx(12 / 20, abs=1e-3)  # episode 1 of the video file: its own span
        # the state is plotted: 12 steps x 14 dimensions
        assert page.get_attribute("canvas[data-key='observation.state']", "data-points") == str(12 * 14)
        data = page.evaluate("() => fetch(document.querySelector('.viewer').dataset.data).then(r => r.json())")
        state = next(s for s in data["keys"] if s["key"] == "observation.state")
        page.click("button.play")
        page.wait_for_function("() => document.querySelector('.viewer').dataset.playing === 'false'", timeout=30_000)
        assert page.get_attribute(".viewer", "data-step") == "11"  # it played to the last step
        assert video.evaluate("v => v.currentTime") >= start + 11 / 20 - 1e-3
        # scrub: the marker and the legend follow, the video seeks into the episode's span
        page.locator("input.scrubber").fill("5")
        assert page.get_attribute("canvas[data-key='observation.state']", "data-marker-step") == "5"
        shown = page.locator("canvas[data-key='observation.state'] ~ .legend .value").all_inner_texts()
        assert [float(v) for v in shown] == pytest.approx([d[5] for d in state["values"]], abs=1e-3)
        page.wait_for_function(f"() => Math.abs(document.querySelector('video').currentTime - {start + 5.5 / 20}) < 0.01")
        painted = page.evaluate(
            """() => { const c = document.querySelector("canvas[data-key='observation.state']");
                      const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
                      for (let i = 0; i < d.length; i += 4) if (d[i] < 200 || d[i + 1] < 200) n++; return n; }"""
        )
        assert painted > 500  # lines were drawn, not an empty frame
        assert problems == [], problems
    finally:
        context.close()


def test_in_a_browser_long_space_strings_wrap_between_numbers_not_inside_them(site, browser):  # noqa: F811
    space = "Dict('agent_pos': Box(-1.0, 1.0, (14,), float32), 'pixels': Box(0, 255, (96, 96, 3), uint8), " * 3
    card = f"# Spaces\n\n- observation space: `{space.strip()}`\n"
    site.api.create_repo("alice/spaces")
    site.api.upload_file(path_or_fileobj=card.encode(), path_in_repo="README.md", repo_id="alice/spaces")
    context = browser.new_context(extra_http_headers={"Authorization": f"Bearer {OWNER}"}, viewport={"width": 700, "height": 900})
    try:
        page = context.new_page()
        page.goto(f"{site.endpoint}/alice/spaces")
        split = page.evaluate(
            """() => { const code = [...document.querySelectorAll('.card li code')].find(c => c.textContent.includes('Dict('));
                      const text = code.firstChild; const out = []; let lines = new Set();
                      for (const m of text.textContent.matchAll(/-?\\d+(\\.\\d+)?/g)) {
                        const r = document.createRange(); r.setStart(text, m.index); r.setEnd(text, m.index + m[0].length);
                        const tops = new Set([...r.getClientRects()].map(x => Math.round(x.top)));
                        if (tops.size > 1) out.push(m[0]);
                        for (const t of tops) lines.add(t);
                      }
                      return [out, lines.size]; }"""
        )
        numbers_split, lines = split
        assert lines > 2  # it does wrap, at this width
        assert numbers_split == []
    finally:
        context.close()


def test_in_a_browser_the_matrix_links_each_cell_to_its_record(site, tiny, matrix_state, browser):  # noqa: F811
    """Once bob's attestation is merged and another is open: a merged cell opens the record's file page, an open one the
    pull request; the favicon loads; nothing on the page logs an error."""
    context = browser.new_context(extra_http_headers={"Authorization": f"Bearer {OWNER}"})
    try:
        page = context.new_page()
        problems = _watch(page)
        page.goto(f"{site.endpoint}/{TINY_REPO}")
        merged, pending = page.locator(".repro-matrix a.cell:not(.pending)"), page.locator(".repro-matrix a.cell.pending")
        assert merged.count() == 1 and pending.count() == 1
        assert page.evaluate("() => fetch('/_hub/static/favicon.svg').then(r => r.status)") == 200
        merged.click()
        page.wait_for_url(re.compile(r"/blob/[0-9a-f]{40}/reproductions/.+\.json$"))
        assert '"verdict": "REPRODUCED"' in page.locator("div.code").inner_text()
        page.go_back()
        page.locator(".repro-matrix a.cell.pending").click()
        page.wait_for_url(re.compile(r"/discussions/\d+$"))
        assert "NOT REPRODUCED" in page.locator(".attestation").inner_text()
        assert problems == [], problems
    finally:
        context.close()


def test_the_viewer_and_the_dataset_writer_agree_on_lerobots_layout():
    """The server imports no client module: the two paths of LeRobot's layout it needs are written twice."""
    from hub_envs.dataset import layout
    from hub_envs.server import episodes

    assert episodes.INFO == layout.INFO_PATH and episodes.EPISODES_DIR == layout.EPISODES_DIR + "/"
