"""Where hub-envs keeps its own local state (the trust list), read at call time.

``$HUB_ENVS_HOME`` if set, else ``$HF_HOME/hub_envs`` (``~/.cache/huggingface/hub_envs``), so a
test that points ``HF_HOME`` at a temp folder also gets a private trust list.
"""

from __future__ import annotations

import os
from pathlib import Path


def hub_envs_home() -> Path:
    if os.environ.get("HUB_ENVS_HOME"):
        return Path(os.environ["HUB_ENVS_HOME"]).expanduser()
    hf_home = os.environ.get("HF_HOME") or os.path.join(os.environ.get("XDG_CACHE_HOME", "~/.cache"), "huggingface")
    return Path(hf_home).expanduser() / "hub_envs"
