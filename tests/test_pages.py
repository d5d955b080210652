"""The embedded Hub's web pages (hub_envs/server/pages.py), against a real ``hub-envs serve``
subprocess holding a real pushed env: first over plain HTTP (what each page says), then in a real
browser (Debian's chromium, driven by Playwright): search, open an env, see its GIF, copy its load
line, open a file; a card with ``<script>`` runs nothing.

The browser tests need ``/usr/bin/chromium``: the ``browser`` fixture installs Debian's ``chromium``
package with apt-get when it is missing (as root, or through passwordless sudo) and skips, saying
why, only when it cannot. Playwright's own browser download (``playwright install``) is never used.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import requests
from helpers import TINY
from huggingface_hub import CommitOperationAdd, HfApi

from hub_envs import push_env

HTML = {"Accept": "text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8"}
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-quic",
    "--disable-component-update",
    "--disable-sync",
]
ENV_REPO = "web/tiny-lerobot"

HOSTILE_CARD = """---
tags:
- hostile
---
# Hostile card

<script>window.pwned = "script"</script>

<img src="x" onerror="window.pwned = 'onerror'">

<div onmouseover="window.pwned = 'div'">hover me</div>

[click me](javascript:window.pwned='link')

![data image](data:image/svg+xml;base64,PHN2Zz48L3N2Zz4=)
"""
HOSTILE_HTML = b"<html><body><script>parent.pwned = 'file'; document.title = 'ran'</script>hi</body></html>"

NOTES_CARD = """---
license: apache-2.0
tags: [notes, tables]
---
# Notes — tables, code and images

| left | right |
|:-----|------:|
| a    | 1     |

```python
def f(x):
    return x + 1
```

![the plot](media/plot.png) and a [link to the code](src/code.py).
"""


def _add(path: str, data: bytes | str) -> CommitOperationAdd:
    return CommitOperationAdd(path_in_repo=path, path_or_fileobj=data.encode() if isinstance(data, str) else data)


def _png() -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (8, 4), (200, 30, 30)).save(buf, format="PNG")
    return buf.getvalue()


@pytest.fixture(scope="module")
def site(hub_module):
    """The module's server holding a real pushed env (push_env of the tiny fixture), a notes repo
    (tables, code, an image, a subfolder) and a repo whose card and files are hostile."""
    api: HfApi = hub_module.api
    pushed = push_env(TINY, ENV_REPO, episodes=2, progress=False)
    api.create_repo("web/notes")
    api.create_commit(
        "web/notes",
        [
            _add("README.md", NOTES_CARD),
            _add("media/plot.png", _png()),
            _add("src/code.py", "import os\n\nprint(os.getcwd())\n"),
            _add("blob.bin", bytes(range(256)) * 4),
        ],
        commit_message="notes",
    )
    api.create_repo("web/hostile")
    api.create_commit("web/hostile", [_add("README.md", HOSTILE_CARD), _add("evil.html", HOSTILE_HTML)], commit_message="hostile")
    return pushed


def _get(hub, path: str, **kw) -> requests.Response:
    return requests.get(hub.endpoint + path, timeout=30, **kw)


# --- plain HTTP ----------------------------------------------------------------------------------


def test_home_lists_repos_newest_first_with_title_tags_commit_and_gif_and_searches(hub_module, site):
    r = _get(hub_module, "/", headers=HTML)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    page = r.text
    # newest commit first: hostile was committed last, the pushed env first
    assert page.index("web/hostile") < page.index("web/notes") < page.index(ENV_REPO)
    assert "tiny-env — a hub-envs environment" in page  # the card's title line
    assert 'href="/?tag=tiny-env"' in page  # its tags
    assert site.sha[:7] in page and "push_env: tiny-env" in page  # its last commit
    assert f'src="/{ENV_REPO}/resolve/{site.sha}/media/rollout.gif"' in page  # its GIF, pinned
    gif = _get(hub_module, f"/{ENV_REPO}/resolve/{site.sha}/media/rollout.gif")
    assert gif.status_code == 200 and gif.content[:6] in (b"GIF87a", b"GIF89a")

    by_name = _get(hub_module, "/?q=TINY", headers=HTML).text
    assert ENV_REPO in by_name and "web/notes" not in by_name
    by_tag = _get(hub_module, "/?tag=tables", headers=HTML).text
    assert "web/notes" in by_tag and ENV_REPO not in by_tag
    by_tag_search = _get(hub_module, "/?q=hostile", headers=HTML).text
    assert "web/hostile" in by_tag_search and "web/notes" not in by_tag_search
    nothing = _get(hub_module, "/?q=no-such-env", headers=HTML)
    assert nothing.status_code == 200 and "No repository matches." in nothing.text


def test_api_paths_are_untouched(hub_module, site):
    r = _get(hub_module, "/")  # an API client (no text/html): the API's answer, as before
    assert r.status_code == 404 and r.headers["content-type"] == "application/json" and "error" in r.json()
    models = _get(hub_module, "/api/models", headers=HTML)  # API paths stay JSON even for a browser
    assert models.headers["content-type"] == "application/json"
    assert ENV_REPO in {m["id"] for m in models.json()}
    info = hub_module.api.model_info(ENV_REPO)
    assert info.sha == site.sha
    readme = _get(hub_module, f"/{ENV_REPO}/resolve/main/README.md", headers=HTML)
    assert readme.status_code == 200 and readme.text.startswith("---")  # the file, not a page


def test_repo_page_renders_the_card_metadata_load_line_files_commits_and_tags(hub_module, site):
    r = _get(hub_module, f"/{ENV_REPO}")
    assert r.status_code == 200
    page = r.text
    assert "Content-Security-Policy" in r.headers and "script-src 'self'" in r.headers["Content-Security-Policy"]
    # the card: Markdown rendered (heading, tables, highlighted code, the GIF at the pinned commit)
    assert "<h1>tiny-env — a hub-envs environment</h1>" in page
    assert '<table class="card-table">' in page
    assert (
        '<pre class="highlight"><code><span class="kn">from</span><span class="w"> </span><span class="nn">hub_envs</span>'
        in page
    )
    assert f'<img src="/{ENV_REPO}/resolve/{site.sha}/media/rollout.gif" alt="Random-action rollouts"' in page
    # YAML metadata: as tags and eval results, never as raw text
    assert "model-index:" not in page and "library_name:" not in page
    assert 'href="/?tag=reinforcement-learning"' in page
    assert "mean_return (random policy)" in page and "success_rate (random policy)" in page
    # the load line, pinned to the commit sha, as push_env prints it
    assert f'<code id="load-line">{site.load_line.replace(chr(34), "&#34;")}</code>' in page
    # files with sizes; folders; commits and tags
    assert 'href="/web/tiny-lerobot/blob/main/tiny.py">tiny.py</a>' in page
    assert 'href="/web/tiny-lerobot/tree/main/dataset">dataset/</a>' in page
    assert re.search(r"tiny\.py</a></td><td class=\"size\">\d+(\.\d)? kB</td>", page)
    assert "push_env: tiny-env" in page and "initial commit" in page
    assert site.content_tag in page and "branch <a" in page

    # a folder, at the content tag: its files, each .parquet marked LFS (the repo's .gitattributes)
    tree = _get(hub_module, f"/{ENV_REPO}/tree/{site.content_tag}/dataset/data/chunk-000").text
    assert re.search(r"file-000\.parquet</a></td><td class=\"size\">[^<]+</td><td><span class=\"lfs\"", tree)
    assert f'commit <a href="/{ENV_REPO}/tree/{site.sha}"><code>{site.sha}</code>' in tree


def test_card_markdown_tables_code_images_links_and_metadata(hub_module, site):
    sha = hub_module.api.model_info("web/notes").sha
    page = _get(hub_module, "/web/notes/tree/main").text
    assert '<th class="align-left">left</th>' in page and '<td class="align-right">1</td>' in page
    assert '<pre class="highlight"><code><span class="k">def</span><span class="w"> </span><span class="nf">f</span>' in page
    assert f'<img src="/web/notes/resolve/{sha}/media/plot.png" alt="the plot"' in page
    assert f'<a href="/web/notes/blob/{sha}/src/code.py">link to the code</a>' in page
    assert "<dt>license</dt><dd>apache-2.0</dd>" in page
    assert 'load-line">snapshot_download(&#34;web/notes&#34;, revision=&#34;' + sha in page  # not an env repo
    assert _get(hub_module, f"/web/notes/resolve/{sha}/media/plot.png").status_code == 200

    api: HfApi = hub_module.api  # other repo types: the same pages under /datasets/ and /spaces/
    api.create_repo("web/data", repo_type="dataset")
    card = b"---\ntags: [data]\n---\n# Data card\n"
    api.upload_file(path_or_fileobj=card, path_in_repo="README.md", repo_id="web/data", repo_type="dataset")
    data = _get(hub_module, "/datasets/web/data").text
    assert "<h1>Data card</h1>" in data and "repo_type=&#34;dataset&#34;" in data
    assert '<span class="badge">dataset</span>' in _get(hub_module, "/?q=web/data", headers=HTML).text


def test_blob_pages_show_text_highlighted_images_inline_and_others_as_downloads(hub_module, site):
    code = _get(hub_module, f"/{ENV_REPO}/blob/{site.sha}/tiny.py")
    assert code.status_code == 200
    assert '<span class="k">class</span><span class="w"> </span><span class="nc">TinyEnv</span>' in code.text
    gif = _get(hub_module, f"/{ENV_REPO}/blob/main/media/rollout.gif").text
    assert f'<img src="/{ENV_REPO}/resolve/{site.sha}/media/rollout.gif"' in gif
    binary = _get(hub_module, "/web/notes/blob/main/blob.bin").text
    assert "This file is not shown here" in binary and 'href="/web/notes/resolve/' in binary and "download" in binary
    parquet = _get(hub_module, f"/{ENV_REPO}/blob/main/dataset/data/chunk-000/file-000.parquet").text
    assert '<span class="lfs">LFS</span>' in parquet and "This file is not shown here" in parquet
    commits = _get(hub_module, f"/{ENV_REPO}/commits/main").text
    assert "push_env: tiny-env" in commits and "initial commit" in commits


@pytest.mark.parametrize(
    ("path", "status", "named"),
    [
        ("/web/nope", 404, "/web/nope"),
        ("/web/tiny-lerobot/tree/v9", 404, "&#39;v9&#39;"),
        ("/web/tiny-lerobot/blob/main/missing.py", 404, "missing.py"),
        ("/web/tiny-lerobot/tree/main/nowhere", 404, "nowhere"),
        ("/web/tiny-lerobot/blob/main/dataset", 404, "dataset is a folder"),
        ("/web/tiny-lerobot/blob/main/%2e%2e/%2e%2e/FORMAT", 400, "Invalid path"),
        ("/web/tiny-lerobot/tree/main/a%2F..%2F..%2Fx", 400, "Invalid path"),
        ("/web/tiny-lerobot/commits/main?p=x", 400, "Invalid page number"),
        ("/_hub/static/nope.js", 404, "nope.js"),
        ("/-bad/name", 400, "Invalid repo id &#39;-bad/name&#39;"),
    ],
)
def test_bad_input_gets_an_html_error_page_naming_what_was_not_found(hub_module, site, path, status, named):
    r = _get(hub_module, path, headers=HTML)
    assert r.status_code == status
    assert r.headers["content-type"].startswith("text/html")
    assert named in r.text


def test_a_hostile_card_is_text_and_repo_files_are_sandboxed(hub_module, site):
    r = _get(hub_module, "/web/hostile")
    page = r.text
    assert "<script>window" not in page and "&lt;script&gt;window.pwned" in page
    assert not re.search(r"<[a-z]+\s[^>]*\bon[a-z]+=", page)  # no element with an event handler (onerror...)
    assert "&lt;img src=&quot;x&quot; onerror=" in page  # the card's <img onerror> is text
    assert 'href="javascript:' not in page and "<script" not in page.replace('<script src="/_hub/static/hub.js"', "")
    csp = r.headers["Content-Security-Policy"]
    assert "default-src 'none'" in csp and "script-src 'self'" in csp and "img-src 'self'" in csp
    raw = _get(hub_module, "/web/hostile/resolve/main/evil.html")  # the file itself, as the API serves it
    assert raw.content == HOSTILE_HTML and "sandbox" in raw.headers["Content-Security-Policy"]
    assert raw.headers["X-Content-Type-Options"] == "nosniff"


def test_private_repos_need_the_token_as_the_api_does(hub_with_token):
    api = hub_with_token.api
    api.create_repo("web/secret", private=True)
    api.create_commit("web/secret", [_add("README.md", "---\ntags: [secret]\n---\n# Secret card\n")], commit_message="secret")
    api.create_repo("web/open")
    auth = {**HTML, "Authorization": f"Bearer {hub_with_token.token}"}

    anonymous = _get(hub_with_token, "/", headers=HTML).text
    assert "web/open" in anonymous and "web/secret" not in anonymous
    page = _get(hub_with_token, "/web/secret", headers=HTML)
    assert page.status_code == 401 and "Secret card" not in page.text and "token" in page.text
    blob = _get(hub_with_token, "/web/secret/blob/main/README.md", headers=HTML)
    assert blob.status_code == 401 and "Secret card" not in blob.text
    assert _get(hub_with_token, "/api/models/web/secret").status_code == 401  # the API's answer, the same

    assert "web/secret" in _get(hub_with_token, "/", headers=auth).text
    page = _get(hub_with_token, "/web/secret", headers=auth)
    assert page.status_code == 200 and "<h1>Secret card</h1>" in page.text
    wrong = _get(hub_with_token, "/web/secret", headers={**HTML, "Authorization": "Bearer wrong"})
    assert wrong.status_code == 401 and "Secret card" not in wrong.text


# --- a real browser ------------------------------------------------------------------------------


def _install_chromium() -> str | None:
    """Install Debian's chromium if it is missing; the reason it cannot be, or None."""
    if CHROMIUM.exists():
        return None
    if shutil.which("apt-get") is None:
        return "no /usr/bin/chromium, and no apt-get to install Debian's chromium package"
    prefix: list[str] = []
    if os.geteuid() != 0:
        if shutil.which("sudo") is None or subprocess.run(["sudo", "-n", "true"], capture_output=True).returncode != 0:
            return "no /usr/bin/chromium, and installing it (apt-get install chromium) needs root or passwordless sudo"
        prefix = ["sudo", "-n"]
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    wait = ["-o", "DPkg::Lock::Timeout=900"]  # both legs of make test run at once: one installs, the other waits
    with open(Path(tempfile.gettempdir()) / "hub-envs-chromium.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if CHROMIUM.exists():
            return None
        for cmd in (
            ["apt-get", *wait, "update", "-qq"],
            ["apt-get", *wait, "install", "-y", "-qq", "--no-install-recommends", "chromium"],
        ):
            done = subprocess.run(prefix + cmd, capture_output=True, text=True, env=env, timeout=900)
            if done.returncode != 0:
                return f"apt-get could not install chromium ({' '.join(cmd)}: {done.stderr.strip()[-300:]})"
    return None if CHROMIUM.exists() else "apt-get installed chromium but /usr/bin/chromium is missing"


@pytest.fixture(scope="module")
def browser() -> Iterator:
    """Debian's chromium, headless, driven by Playwright (installed with apt-get if missing)."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed: `make install` (the dev extra) installs it")
    reason = _install_chromium()
    if reason:
        pytest.skip(reason)
    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


def test_in_a_browser_search_open_see_the_gif_copy_the_load_line_and_open_a_file(hub_module, site, browser):
    context = browser.new_context(permissions=["clipboard-read", "clipboard-write"])
    try:
        page = context.new_page()
        page.goto(hub_module.endpoint + "/")
        assert {ENV_REPO, "web/notes", "web/hostile"} <= set(page.locator(".repo-name").all_inner_texts())
        page.fill("input[name=q]", "tiny")
        page.press("input[name=q]", "Enter")
        page.wait_for_url(re.compile(r"\?q=tiny$"))
        # the env repo, and the dataset repo of the same name push_env publishes its dataset to (for LeRobot's tools)
        assert page.locator(".repo-name").all_inner_texts() == [ENV_REPO, ENV_REPO]
        assert sorted(page.locator(".repo-name").evaluate_all("els => els.map(e => e.getAttribute('href'))")) == [
            f"/datasets/{ENV_REPO}",
            f"/{ENV_REPO}",
        ]

        page.click(f"a.repo-name[href='/{ENV_REPO}']")
        page.wait_for_url(hub_module.endpoint + f"/{ENV_REPO}")
        gif = page.locator(".card img").first
        gif.wait_for()
        page.wait_for_function("img => img.complete", arg=gif.element_handle())
        assert gif.evaluate("img => img.naturalWidth") > 0
        assert gif.get_attribute("src") == f"/{ENV_REPO}/resolve/{site.sha}/media/rollout.gif"

        page.click("button[data-copy=load-line]")
        page.wait_for_function("() => document.querySelector('button[data-copy]').textContent === 'Copied'")
        assert page.evaluate("navigator.clipboard.readText()") == site.load_line

        page.click("a:text-is('tiny.py')")
        page.wait_for_url(hub_module.endpoint + f"/{ENV_REPO}/blob/main/tiny.py")
        assert "TinyEnv" in page.locator(".code .highlight .nc").all_inner_texts()  # a class name, highlighted
    finally:
        context.close()


def test_in_a_browser_a_card_with_script_runs_nothing(hub_module, site, browser):
    context = browser.new_context()
    try:
        page = context.new_page()
        dialogs: list[str] = []
        page.on("dialog", lambda d: (dialogs.append(d.message), d.dismiss()))
        page.goto(hub_module.endpoint + "/web/hostile")
        page.wait_for_load_state("load")
        assert page.locator("h1", has_text="Hostile card").count() == 1
        page.hover("text=hover me")
        page.click("text=click me")  # a javascript: link is not a link: nothing happens
        assert page.evaluate("typeof window.pwned") == "undefined"
        assert page.url == hub_module.endpoint + "/web/hostile"

        page.goto(hub_module.endpoint + "/web/hostile/resolve/main/evil.html")  # a repo's HTML file, opened
        page.wait_for_load_state("load")
        assert page.title() != "ran" and page.evaluate("typeof window.pwned") == "undefined"
        assert dialogs == []
    finally:
        context.close()
