"""``hub-envs serve``: run the loopback Hub-protocol server."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hub_envs.errors import MissingRequirementsError


@dataclass
class Config:
    """Run the loopback Hub-protocol server."""

    root: Path = Path("./hub-data")  # the folder the repos are kept in (created if missing)
    host: str = "127.0.0.1"  # the address to listen on (loopback by default)
    port: int = 8000  # the port to listen on
    token: str | None = None  # if set, writes and private reads need it (Authorization: Bearer; clients: HF_TOKEN=<token>)
    max_body_mb: float | None = None  # largest request body; default: $HUB_ENVS_SERVER_MAX_BODY_MB, else 2048
    max_line_mb: float | None = None  # largest commit line (one base64 file); default: $HUB_ENVS_SERVER_MAX_LINE_MB, else 16
    max_lfs_mb: float | None = None  # largest LFS file; default: $HUB_ENVS_SERVER_MAX_LFS_MB, else 51200 (the Hub's 50 GB)
    # seconds to send a request head, then 408; default: $HUB_ENVS_SERVER_HEADER_TIMEOUT, else 20
    header_timeout: float | None = None
    max_connections: int | None = None  # connections open at once, then 503; default: $HUB_ENVS_SERVER_MAX_CONNECTIONS, else 1000


def main(config: Config) -> int:
    """Serve the loopback Hub until interrupted.

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    try:
        from hub_envs.server import run  # heavy: starlette, uvicorn (the server extra, maybe not installed)
    except ModuleNotFoundError as exc:
        if exc.name not in ("starlette", "uvicorn", "markdown_it", "pygments"):
            raise
        raise MissingRequirementsError(
            f"hub-envs serve needs {exc.name}, which is not installed. Install the server extra: pip install 'hub-envs[server]'"
        ) from None
    run(
        root=config.root,
        host=config.host,
        port=config.port,
        token=config.token,
        max_body_mb=config.max_body_mb,
        max_line_mb=config.max_line_mb,
        max_lfs_mb=config.max_lfs_mb,
        header_timeout=config.header_timeout,
        max_connections=config.max_connections,
    )
    return 0
