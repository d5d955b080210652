"""The ``hub-envs`` command (and the ``push_env`` console script): one table of commands, each in a module of its own.

Flags are draccus-style, as in LeRobot's CLIs: ``--key=value`` (``--key value`` works too); a command that takes a
repo id takes it first, without its flag, too. Every hub-envs error is printed as one message (what failed, what to do
next) with exit code 1; a command or flag that does not exist, with exit code 2 and the closest one named, before any
library is imported.

    hub-envs serve --root=./hub-data --port=8000 [--token=T]
    push_env --env_dir=envs/pendulum --repo_id=user/pendulum-lerobot [--episodes=10] [--backend=ray]
    hub-envs load user/pendulum-lerobot@<sha> [--trust_remote_code=true] [--isolation=process]
    hub-envs trust user/pendulum-lerobot@<sha>
    hub-envs reproduce user/pendulum-lerobot --revision=<sha> --trust_remote_code=true [--attest=true]
    hub-envs audit user/name[@rev][:path] --trust_remote_code=true
    hub-envs adopt --from_repo=user/name@<sha>[:path] --repo_id=me/name --trust_remote_code=true
    hub-envs --version
    hub-envs train --env.type=hub --env.repo_id=user/pendulum-lerobot --env.revision=<sha> --policy.type=act ...
"""

from __future__ import annotations

import importlib
import sys
import warnings
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from hub_envs.cli.argv import flag_names, parse_config, suggest
from hub_envs.cli.version import version_text
from hub_envs.errors import HubEnvsError, UsageError
from hub_envs.repo.refs import check_repo_flags


@dataclass(frozen=True)
class Command:
    """One ``hub-envs`` command: its module (``hub_envs.cli.<module>``) and the line ``hub-envs --help`` shows.

    The module is imported when the command runs, never for ``hub-envs --help``, and imports its library only in
    ``main`` (which may import lerobot and torch). It has a ``Config`` dataclass (its flags, parsed by draccus; every
    field with a help comment) and ``main(config)``; a positional value fills ``--repo_id`` (or the fields its
    ``POSITIONAL`` names). Or, with ``ARGV = True``, ``main(argv, prog)``: it parses its arguments itself (``push``'s
    ``--config.<field>`` variants, ``train``/``eval``: LeRobot's parser), checking them before its library too.
    """

    module: str
    summary: str


#: Every command, in the order ``hub-envs --help`` lists them.
COMMANDS: dict[str, Command] = {
    "serve": Command("serve", "run the loopback Hub-protocol server"),
    "push": Command("push", "validate an env folder, generate its dataset and card, publish it in one commit (also: push_env)"),
    "load": Command("load", "load an env repo, run its checks, print the three-way feature table"),
    "audit": Command("audit", "check a plain LeRobot EnvHub repo against LeRobot's conventions; publishes nothing"),
    "adopt": Command("adopt", "publish a hub-envs repo from a plain LeRobot EnvHub repo, pinned to its commit"),
    "trust": Command("trust", "trust one commit of a repo: hub-envs trust user/name@<sha>"),
    "untrust": Command("untrust", "forget the trust entries of a repo: hub-envs untrust user/name[@<sha>]"),
    "reproduce": Command("reproduce", "re-run what a repo recorded (dataset replay, benchmarks, fingerprint) and report"),
    "evaluate": Command("evaluate", "a policy over N seeded episodes, locally or on a Ray cluster (--backend=ray)"),
    "diff": Command("diff", "what changed between two revisions (files, manifest, spaces) and where their behaviour diverges"),
    "attestations": Command(
        "attestations", "a repo's reproduction attestations (merged and in open PRs): env revision x stack -> verdict"
    ),
    "compare": Command(
        "compare", "evaluate policies (LeRobot checkpoints, random) on the same seeds: rates, CIs, paired difference"
    ),
    "train": Command("train", "LeRobot's lerobot-train with a hub env (--env.type=hub --env.repo_id=...)"),
    "eval": Command("eval", "LeRobot's lerobot-eval with a hub env (--env.type=hub --env.repo_id=...)"),
}

#: what an interrupted command leaves behind, said after "interrupted (Ctrl-C)"
INTERRUPTED_NOTES = {
    "push": " push_env builds the repo in a temporary folder (now removed) and makes its one commit only after every "
    "episode is written: an interrupted build published nothing. Run the same command again (on Ray with --out=DIR, "
    "the finished shards are kept and skipped).",
}


def main(argv: list[str] | None = None) -> int:
    """The ``hub-envs`` console script: ``hub-envs <command> [repo id] [--flag=value ...]``, or ``hub-envs --version``.

    Args:
        argv: the arguments (default: ``sys.argv[1:]``).

    Returns:
        The exit code: 0 done, 1 a hub-envs error (printed as one message), 2 a command line that names no such command
        or flag (:class:`~hub_envs.errors.UsageError`, "did you mean" in the message), 130 interrupted.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"}:
        print(usage(), file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    if argv[0] in {"-V", "--version"}:
        print(version_text())
        return 0
    return run_command(argv[0], argv[1:])


def push_env_main(argv: list[str] | None = None) -> int:
    """The ``push_env`` console script (``hub-envs push``): ``push_env --env_dir=... --repo_id=...``.

    Args:
        argv: the arguments (default: ``sys.argv[1:]``).

    Returns:
        The exit code (see :func:`main`).
    """
    return run_command("push", list(sys.argv[1:] if argv is None else argv), prog="push_env")


def run_command(name: str, argv: list[str], *, prog: str | None = None) -> int:
    """Run one command with its arguments: the command line checked (before any heavy import), parsed, run.

    Args:
        name: a key of :data:`COMMANDS`.
        argv: its arguments.
        prog: how usage lines and messages name the command (default: ``hub-envs <name>``).

    Returns:
        The exit code (see :func:`main`).
    """
    warnings.formatwarning = _format_warning  # a CLI user needs the message, not our source line
    prog = prog or f"hub-envs {name}"
    try:
        command = command_module(name)
        if getattr(command, "ARGV", False):  # parses its arguments itself
            check_repo_flags(argv)  # before any parser: draccus drops a trailing newline of a flag's value
            return int(command.main(argv, prog) or 0)
        return int(command.main(parse_command(name, argv, prog=prog)) or 0)
    except UsageError as e:
        print(f"error: {type(e).__name__}: {e}", file=sys.stderr)
        return 2  # as argparse (and so draccus) exits on a command line it cannot read
    except HubEnvsError as e:
        print(f"error: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # the work in flight (worker processes, Ray tasks) was stopped on the way out
        note = INTERRUPTED_NOTES.get(name, "")
        print(f"\n{prog}: interrupted (Ctrl-C); the work in flight was stopped.{note}", file=sys.stderr)
        return 130  # 128 + SIGINT, as a shell reports it


def command_module(name: str) -> ModuleType:
    """The module of command ``name`` (light: a command imports its library only when it runs).

    Args:
        name: what was typed as the command.

    Returns:
        ``hub_envs.cli.<module>``.

    Raises:
        UsageError: no such command; the message names the closest one.
    """
    if name not in COMMANDS:
        close = suggest(name, [*COMMANDS, "--help", "--version"])
        hint = f": did you mean {close!r}?" if close else "."
        raise UsageError(f"hub-envs has no command {name!r}{hint} (hub-envs --help lists the commands)")
    return importlib.import_module(f"hub_envs.cli.{COMMANDS[name].module}")


def parse_command(name: str, argv: list[str], *, prog: str | None = None) -> Any:
    """The ``Config`` of command ``name`` from its arguments, as the command would run with them: a positional repo
    id is its ``--repo_id`` (``hub-envs diff``: ``--old`` and ``--new``), every flag checked against the command's
    (``push``: without its ``--config.<field>`` flags, which its ``main`` splits off first).

    Args:
        name: a key of :data:`COMMANDS` whose module has a ``Config``.
        argv: its arguments.
        prog: how usage lines and messages name the command (default: ``hub-envs <name>``).

    Returns:
        The command's ``Config``.

    Raises:
        UsageError: no such command or flag, or a repo id given twice, differently.
        ConfigError: a repo flag holding a newline, a control character or surrounding spaces.
        SystemExit: draccus' answer to ``--help`` (0) or to a value it cannot read (2).
    """
    prog = prog or f"hub-envs {name}"
    command = command_module(name)
    names = flag_names(command.Config)
    positional = getattr(command, "POSITIONAL", ("repo_id",) if "repo_id" in names else ())
    return parse_config(prog, command.Config, argv, positional=positional)


def usage() -> str:
    """What ``hub-envs --help`` prints: every command and its line."""
    width = max(map(len, COMMANDS))
    lines = "\n".join(f"  {name:<{width}}  {command.summary}" for name, command in COMMANDS.items())
    return (
        f"usage: hub-envs <command> [user/name[@revision]] [--flag=value ...]\n"
        f"       hub-envs --version\n\ncommands:\n{lines}\n\n"
        f"Run `hub-envs <command> --help` for the flags of one command."
    )


def _format_warning(message, category, filename, lineno, line=None) -> str:
    return f"warning: {message}\n"
