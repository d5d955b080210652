"""Regenerate docs/hub-home.png and docs/hub-repo.png (docs/server.md's screenshots of the web page).

    make demo SERVE=1            # in one shell: publishes envs/{pendulum,hover,reach}, keeps the server up
    .venv/bin/python scripts/screenshot-pages.py http://127.0.0.1:PORT docs

Headless Debian chromium (/usr/bin/chromium) through Playwright; the PNGs are quantized to 128 colours.
"""

import sys

from PIL import Image
from playwright.sync_api import sync_playwright

ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
        "--disable-quic", "--disable-component-update", "--disable-sync"]
base, out = sys.argv[1].rstrip("/"), sys.argv[2]
with sync_playwright() as p:
    browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
    for name, url, full, height in [("hub-home", "/", True, 380), ("hub-repo", "/demo/reach-lerobot", False, 900)]:
        page = browser.new_page(viewport={"width": 1280, "height": height})
        page.goto(base + url)
        page.wait_for_load_state("networkidle")
        page.wait_for_function("() => [...document.images].every(i => i.complete && i.naturalWidth > 0)")
        path = f"{out}/{name}.png"
        page.screenshot(path=path, full_page=full)
        Image.open(path).convert("RGB").quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    browser.close()
