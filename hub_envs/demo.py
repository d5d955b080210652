"""``make demo``: the whole job on the embedded loopback Hub (serve, push each example env, load it back pinned);
``python -m hub_envs.demo [--episodes=N] [--out=demo-out] [--serve] [envs/pendulum ...]``.
"""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
import time
from pathlib import Path

from hub_envs.loading.load import load_env
from hub_envs.paths import PACKAGE_DIR
from hub_envs.publishing.push import push_env
from hub_envs.testing import HubServer, hub_environment

REPO_ROOT = PACKAGE_DIR.parent
DEFAULT_ENVS = ["pendulum", "hover", "reach"]


def main(argv: list[str] | None = None) -> int:
    """Run the demo.

    Args:
        argv: its arguments (default: ``sys.argv[1:]``).

    Returns:
        The exit code.
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("env_dirs", nargs="*", help="env folders (default: envs/pendulum, envs/hover, envs/reach)")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "demo-out")
    parser.add_argument("--namespace", default="demo")
    parser.add_argument("--serve", action="store_true", help="keep the server (and its web page) up until Ctrl-C")
    args = parser.parse_args(argv)

    env_dirs = [Path(d) for d in args.env_dirs] or [
        REPO_ROOT / "envs" / n for n in DEFAULT_ENVS if (REPO_ROOT / "envs" / n).is_dir()
    ]
    if not env_dirs:
        env_dirs = [REPO_ROOT / "tests" / "fixtures" / "tiny_env"]
    if args.out.exists():
        shutil.rmtree(args.out)
    args.out.mkdir(parents=True)

    t0 = time.perf_counter()
    with HubServer(args.out / "hub-data") as server:
        print(f"Loopback Hub running at {server.endpoint} (store: {server.root})")
        published = []
        with hub_environment(server.endpoint, args.out / "publisher_home"):
            for env_dir in env_dirs:
                repo_id = f"{args.namespace}/{env_dir.name}-lerobot"
                print(
                    f"\n=== push_env --env_dir={env_dir.relative_to(REPO_ROOT) if env_dir.is_relative_to(REPO_ROOT) else env_dir} --repo_id={repo_id} --episodes={args.episodes}"
                )
                t = time.perf_counter()
                result = push_env(env_dir, repo_id, episodes=args.episodes)
                print(result.summary())
                print(f"(push took {time.perf_counter() - t:.1f}s)")
                published.append(result)

        # a different user, a fresh cache: load each back by repo id, pinned to the pushed sha
        with hub_environment(server.endpoint, args.out / "user_home"):
            for result in published:
                print(f'\n=== load_env("{result.repo_id}@{result.sha}", trust_remote_code=True)')
                t = time.perf_counter()
                loaded = load_env(f"{result.repo_id}@{result.sha}", trust_remote_code=True)
                print(f"resolved sha {loaded.revision}; gym id {loaded.gym_id!r}; --env.type={loaded.env_type}")
                print(f"integrity: {loaded.report.integrity}; fingerprint: {loaded.report.fingerprint}")
                print(loaded.report.features.table())
                print(f"card: {loaded.path / 'README.md'}")
                print(f"GIF:  {loaded.media_file('rollout.gif')}")  # load_env leaves the media on the Hub
                print(f"(cold load took {time.perf_counter() - t:.1f}s)")
        print(
            f"\nWeb page: {server.endpoint}/ (the envs: " + ", ".join(f"{server.endpoint}/{r.repo_id}" for r in published) + ")"
        )
        if args.serve:
            print(f"Demo done in {time.perf_counter() - t0:.0f}s. Serving {server.endpoint}/ until Ctrl-C.", flush=True)
            # Ctrl-C (even when started with SIGINT ignored, as from a background job) or SIGTERM: stop
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.signal(signal.SIGTERM, signal.default_int_handler)
            try:
                while server.running:
                    time.sleep(0.5)
            except KeyboardInterrupt:
                print(f"\nServer stopped. Everything is under {args.out}.", flush=True)
                return 0
            print(f"The server exited on its own:\n{server.output()[-2000:]}", file=sys.stderr)
            return 1
    print(f"\nDemo done in {time.perf_counter() - t0:.0f}s; server stopped. Everything is under {args.out}.")
    print("(make demo SERVE=1 keeps the server and its web page up until Ctrl-C.)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
