"""Shared pytest fixtures.

The ``hub`` fixtures come first: a real loopback Hub server (a subprocess) per test, with the
client environment pointed at it. Other fixtures are added below this block by others.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from huggingface_hub import HfApi

from hub_envs.testing import HubServer, hub_environment

TEST_TOKEN = "hf_hub_envs_test_token"


@dataclass
class Hub:
    """What the ``hub`` fixtures yield: a running server and a client environment pointed at it."""

    server: HubServer
    endpoint: str
    token: str | None
    root: Path
    hf_home: Path
    api: HfApi


def _start_hub(tmp_path: Path, token: str | None, suffix: str = "", env: dict[str, str] | None = None) -> Iterator[Hub]:
    # distinct folders per variant: a test may use both `hub` and `hub_with_token`
    server = HubServer(tmp_path / f"hub-data{suffix}", token=token, env=env)
    try:
        hf_home = tmp_path / f"hf_home{suffix}"
        with hub_environment(server.endpoint, hf_home, token=token):
            yield Hub(
                server=server,
                endpoint=server.endpoint,
                token=token,
                root=server.root,
                hf_home=hf_home,
                api=HfApi(endpoint=server.endpoint, token=token),
            )
    finally:
        # SIGKILL, not SIGTERM: the store is crash-safe and this root is thrown away, and a
        # graceful stop costs ~0.15 s per test.
        server.kill()
        server.remove_log()


@pytest.fixture
def hub(tmp_path: Path) -> Iterator[Hub]:
    """A loopback Hub server open to writes (no token), ``HF_ENDPOINT``/``HF_HOME`` pointed at it."""
    yield from _start_hub(tmp_path, token=None)


@pytest.fixture
def hub_with_token(tmp_path: Path) -> Iterator[Hub]:
    """Like ``hub``, but the server was started with ``--token``; ``HF_TOKEN`` holds that token."""
    yield from _start_hub(tmp_path, token=TEST_TOKEN, suffix="-token")


# --- other fixtures below ----------------------------------------------------------------------


@pytest.fixture
def hub_storing_bytecode(tmp_path: Path) -> Iterator[Hub]:
    """Like ``hub``, but the server stores ``.pyc`` files in env repos as huggingface.co does (the loopback
    server refuses them): for tests of what a client does with bytecode a hostile repo on the real Hub holds."""
    yield from _start_hub(tmp_path, token=None, suffix="-bytecode", env={"HUB_ENVS_SERVER_ALLOW_BYTECODE": "1"})


@pytest.fixture(scope="module")
def hub_module(tmp_path_factory) -> Iterator[Hub]:
    """Like ``hub``, but one server for a whole test module (give each test its own repo names)."""
    yield from _start_hub(tmp_path_factory.mktemp("hub-module"), token=None)
