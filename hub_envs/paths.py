"""Where hub-envs' own files are: its package folder, and its local state (the trust list, the check cache)."""

from __future__ import annotations

import os
from pathlib import Path

#: The hub_envs package's folder (its templates, its sources).
PACKAGE_DIR = Path(__file__).resolve().parent


def hub_envs_home() -> Path:
    """Where hub-envs keeps its own state.

    Never inside the Hugging Face cache, whose file names a Hub endpoint chooses. Tests point ``HUB_ENVS_HOME`` at a
    temp folder (:func:`hub_envs.testing.hub_environment` does).

    Returns:
        ``$HUB_ENVS_HOME`` if set, else ``$XDG_STATE_HOME/hub-envs`` (``~/.local/state/hub-envs``).
    """
    if os.environ.get("HUB_ENVS_HOME"):
        return Path(os.environ["HUB_ENVS_HOME"]).expanduser()
    return Path(os.environ.get("XDG_STATE_HOME") or "~/.local/state").expanduser() / "hub-envs"


def legacy_hub_envs_home() -> Path:
    """Where hub-envs before content-bound trust kept its state: ``$HF_HOME/hub_envs`` (read only to explain)."""
    hf_home = os.environ.get("HF_HOME") or os.path.join(os.environ.get("XDG_CACHE_HOME", "~/.cache"), "huggingface")
    return Path(hf_home).expanduser() / "hub_envs"
