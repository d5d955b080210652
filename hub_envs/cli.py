"""The ``hub-envs`` command line (and the ``push_env`` console script).

Flags are draccus-style, as in LeRobot's CLIs: ``--key=value`` (``--key value`` works too).

    hub-envs serve --root=./hub-data --port=8000 [--token=T]
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import draccus


@dataclass
class ServeArgs:
    """Run the loopback Hub-protocol server."""

    root: Path = Path("./hub-data")
    host: str = "127.0.0.1"
    port: int = 8000
    token: str | None = None


def serve(args: ServeArgs) -> int:
    from hub_envs.server import run

    run(root=args.root, host=args.host, port=args.port, token=args.token)
    return 0


COMMANDS = {
    "serve": (ServeArgs, serve),
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"} or argv[0] not in COMMANDS:
        names = ", ".join(COMMANDS)
        print(f"usage: hub-envs {{{names}}} [--flag=value ...]\n"
              f"Run `hub-envs <command> --help` for the flags of one command.", file=sys.stderr)
        return 0 if argv and argv[0] in {"-h", "--help"} else 2
    args_cls, func = COMMANDS[argv[0]]
    args = draccus.parse(config_class=args_cls, args=argv[1:])
    return int(func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
