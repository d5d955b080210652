"""What every backend is: a :class:`Backend` turns ``(env, seeds, max_steps, policy)`` into the episodes' rollouts,
**in episode order**, whatever runs them; an :class:`EnvSource` is how a worker elsewhere gets the env the way a user
does. The results are identical on every backend for any number of workers (an episode is fully determined by its
seed, its policy and ``max_steps``: :mod:`hub_envs.harness.rollout`)."""

from __future__ import annotations

import io
import tarfile
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hub_envs.envcode.envconfig import encode_config
from hub_envs.harness.rollout import EpisodeRollout
from hub_envs.loading.load import load_env
from hub_envs.repo.format import list_files


@dataclass(frozen=True)
class EnvSource:
    """How a worker on another machine gets the env the way a user does.

    ``ref`` is ``user/name@<sha>`` for a Hub repo (the worker calls ``load_env`` on it: the Hub distributes
    the code and integrity is verified there), or the folder name of a local env folder whose files travel
    with the job as ``folder`` (a tar archive, through Ray's object store). ``config`` is the variant's
    config fields (a local folder); ``identity`` names the exact content (for checkpoints). ``isolation`` is the
    :func:`~hub_envs.load_env` isolation keywords the env was loaded with (empty: in-process): a worker loads it
    the same way, so with ``isolation="process"`` the env's code runs in a worker process of the Ray worker.
    ``content_digest`` is the manifest's content digest the driver's consent covers: a worker's load refuses a
    commit that holds anything else (its path to the Hub may differ from the driver's). ``token`` is the Hub
    token the worker downloads with (None: the worker node's own, if it has one). ``task``: the suite task the env makes
    (:meth:`~hub_envs.loading.loaded.LoadedEnv.for_task`; None: the published config's), named in ``identity`` too.
    """

    ref: str
    identity: str
    folder: bytes | None = None
    config: dict[str, Any] = field(default_factory=dict)
    trust_remote_code: bool = False
    token: str | None = field(default=None, repr=False)
    isolation: dict[str, Any] = field(default_factory=dict)
    content_digest: str | None = None
    task: str | None = None

    @classmethod
    def from_loaded(cls, loaded: Any) -> EnvSource:
        """The source of an env this process loaded: consent given here carries over to the workers, bound to the content it
        was given for.

        Args:
            loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

        Returns:
            A Hub repo's ``user/name@<sha>`` with its content digest, or a local folder's files as a tar archive.
        """
        isolation = loaded.isolation.load_kwargs() if getattr(loaded, "isolation", None) is not None else {}
        task = getattr(loaded, "task", None)
        of_task = f"#task={task}" if task is not None else ""  # a suite task's episodes are other episodes
        if loaded.local_folder is not None:
            values = encode_config(loaded.config)
            config = {name: values[name] for name in sorted(loaded.manifest.config_overrides)}
            return cls(
                ref=Path(loaded.local_folder).name,
                identity=f"{loaded.repo_id}@{loaded.revision}{of_task}",
                folder=_tar_folder(Path(loaded.local_folder)),
                config=config,
                isolation=isolation,
                task=task,
            )
        # a plain EnvHub repo's entry file is part of what to load (user/name@<sha>:path): without it a worker made env.py
        ref = getattr(loaded, "plain_source", None) or f"{loaded.repo_id}@{loaded.revision}"
        digest = loaded.manifest.content_digest
        return cls(
            ref=ref,
            identity=f"{ref}#{digest}{of_task}",  # a commit id alone is what the endpoint says it is: the content is named too
            trust_remote_code=True,
            token=getattr(loaded, "token", None),
            isolation=isolation,
            content_digest=digest,
            task=task,
        )

    def load(self, scratch: Path | None = None) -> Any:
        """``load_env`` in this (worker) process, with the driver's isolation; the checks already ran where the run was started.

        Args:
            scratch: where a shipped folder is unpacked (the caller removes it; default: a new temp folder).

        Returns:
            The :class:`~hub_envs.loading.loaded.LoadedEnv`.

        Raises:
            UntrustedCodeError: the commit holds other content than the driver's consent covers.
            hub_envs.errors.HubEnvsError: as :func:`hub_envs.load_env`.
        """
        loaded = self._load(scratch)
        return loaded.for_task(self.task) if self.task is not None else loaded

    def _load(self, scratch: Path | None) -> Any:
        if self.folder is None:
            return load_env(
                self.ref,
                trust_remote_code=self.trust_remote_code,
                check=False,
                fingerprint="off",
                token=self.token,
                content_digest=self.content_digest,  # the driver's consent covers this content only
                **self.isolation,
            )
        root = Path(scratch) if scratch is not None else Path(tempfile.mkdtemp(prefix="hub-envs-worker-"))
        with tarfile.open(fileobj=io.BytesIO(self.folder), mode="r") as tar:
            tar.extractall(root, filter="data")
        return load_env(root / self.ref, check=False, config=self.config or None, **self.isolation)


def _tar_folder(folder: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for rel in list_files(folder):
            tar.add(folder / rel, arcname=f"{folder.name}/{rel}", recursive=False)
    return buf.getvalue()


class Backend:
    """Runs episodes of a loaded env and yields their rollouts in episode order.

    Backends are context managers: ``with backend:`` keeps a Ray connection (or the local Ray it started) for several
    runs; without it each run connects and disconnects by itself.
    """

    name = "backend"

    def __enter__(self) -> Backend:
        return self

    def __exit__(self, *exc: Any) -> None:
        return None

    def episodes(
        self,
        loaded: Any,
        seeds: Sequence[int],
        *,
        max_steps: int,
        policy: Any = None,
        record_states: bool = False,
        progress: bool = True,
        desc: str = "rollouts",
    ) -> Iterator[EpisodeRollout]:
        """Rollouts of ``loaded``'s env, one per seed, in seed order.

        Args:
            loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.
            seeds: one reset seed per episode.
            max_steps: at most this many steps per episode.
            policy: as :func:`~hub_envs.harness.rollout.run_episodes` takes it (None: the seeded random policy).
            record_states: record ``env.get_state()`` before each action.
            progress: show a progress bar.
            desc: the bar's label.

        Returns:
            An iterator of :class:`~hub_envs.harness.rollout.EpisodeRollout`, in episode order.

        Raises:
            EnvCodeError: an episode raised.
        """
        raise NotImplementedError

    def settings(self) -> dict[str, Any]:
        """What a report records about where the episodes ran (the results do not depend on it)."""
        return {"backend": self.name}
