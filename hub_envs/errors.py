"""Every error hub-envs raises on purpose.

One hierarchy, rooted at :class:`HubEnvsError`, so callers can catch all of them at once, and one
class for each way things fail, so they can catch exactly one. Every message names the repo,
revision, file or field involved and ends with what to do next.

Example:
    >>> from hub_envs.errors import HubEnvsError, UntrustedCodeError
    >>> issubclass(UntrustedCodeError, HubEnvsError)
    True
"""

from __future__ import annotations


class HubEnvsError(Exception):
    """Base class of every error hub-envs raises on purpose."""


# --- finding things ---------------------------------------------------------------------------


class EnvRepoNotFoundError(HubEnvsError, LookupError):
    """The repo id does not exist on the Hub (or is private and no token grants access)."""


class RevisionNotFoundError(HubEnvsError, LookupError):
    """The repo exists but the branch, tag or commit sha does not."""


class OfflineNotCachedError(HubEnvsError, LookupError):
    """Offline mode (HF_HUB_OFFLINE=1) was asked for, but the revision is not in the local cache."""


# --- the repo format --------------------------------------------------------------------------


class InvalidRepoFormatError(HubEnvsError, ValueError):
    """A file of the env repo (or local env folder) is missing, unreadable or malformed."""


class ManifestError(InvalidRepoFormatError):
    """The manifest (hub_env.json) is missing, is not valid JSON, or a field is wrong."""


class EnvFolderError(InvalidRepoFormatError):
    """A local env folder (what push_env publishes) is not in the documented shape."""


class IntegrityError(HubEnvsError):
    """A downloaded file differs from the sha256 the manifest records, or is missing or unlisted."""


# --- running code -----------------------------------------------------------------------------


class UntrustedCodeError(HubEnvsError, PermissionError):
    """The repo's code would run, but nobody consented for this exact repo@sha."""


class MissingRequirementsError(HubEnvsError, ImportError):
    """Packages the repo requires are missing or at incompatible versions. Nothing is installed."""


class EnvCodeError(HubEnvsError, RuntimeError):
    """The repo's code failed: it raised on import, in reset or step, or broke the env contract."""


class EnvContractError(EnvCodeError):
    """A plain LeRobot EnvHub repo's entry file breaks LeRobot's EnvHub contract: no ``make_env(n_envs, use_async_envs,
    cfg=None)``, or it returns something other than a ``gym.Env``, a ``VectorEnv`` or ``{suite: {task_id: VectorEnv}}``."""


class RegistrationConflictError(HubEnvsError, ValueError):
    """The gym id or draccus choice name is already taken by something else."""


# --- checks -----------------------------------------------------------------------------------


class CheckError(HubEnvsError):
    """A check on the env failed (base class of the specific check failures)."""


class EnvCheckError(CheckError):
    """gymnasium's env checker refused the env."""


class FeatureMismatchError(CheckError):
    """Declared features, live rollouts and the dataset disagree. ``.table`` lists every disagreement."""

    def __init__(self, message: str, mismatches: list | None = None, table: str = ""):
        super().__init__(message)
        self.mismatches = list(mismatches or [])
        self.table = table


class DeterminismError(CheckError):
    """The same seed did not give the same rollout."""


class FingerprintMismatchError(CheckError):
    """The golden-rollout fingerprint recomputed on load differs from the published one."""


class DatasetError(HubEnvsError):
    """The bundled LeRobot dataset is missing, malformed, or cannot be written."""


class DatasetNotCachedError(OfflineNotCachedError, DatasetError):
    """An env's dataset files are not in the local cache and the Hub cannot be used to fetch them."""


class ReproductionError(HubEnvsError):
    """A replay or benchmark reproduction could not be run (not: it ran and diverged)."""


class ConfigError(HubEnvsError, ValueError):
    """A configuration value (CLI flag, EnvConfig field, setting) is invalid."""


class UsageError(ConfigError):
    """A command line names no such command or flag, or gives one value two ways; the CLI exits with code 2, as
    argparse does, and the message says what was probably meant."""


class AttestationError(HubEnvsError, ValueError):
    """A reproduction attestation is malformed, or could not be signed, verified or published."""


class ClusterUnreachableError(HubEnvsError, ConnectionError):
    """``--backend=ray``: nothing answers at the Ray address (``--ray_address`` or ``RAY_ADDRESS``); the message names it."""


class ClusterAuthError(ClusterUnreachableError):
    """``--backend=ray``: the Ray cluster uses token authentication and refused this process (Ray's ``InvalidAuthToken``);
    the message says what to set (``RAY_AUTH_MODE=token`` and where the cluster's token goes)."""


class ProcessorError(InvalidRepoFormatError):
    """An env processor declared in the manifest is malformed or cannot be built."""


class HubError(HubEnvsError):
    """The Hub (or the loopback server) refused or failed a request that is not covered above."""


class HostileResponseError(HubError, IntegrityError):
    """The endpoint answered something no Hub sends (a non-hex ETag or commit id, a path escaping the repo):
    refused before the client wrote anything with it."""


class HubAccessError(HubError, PermissionError):
    """The Hub will not let this caller write the repo: no token, a token it refuses, a read-only token, or an
    account that cannot write the namespace. Raised before anything is built."""


class ConcurrentPushError(HubError):
    """The repo's main moved while push_env was preparing its commit (another push landed first); nothing was written."""


# --- isolated envs (hub_envs.isolation) ----------------------------------------------------------


class IsolationError(HubEnvsError):
    """An isolated env (``load_env(..., isolation="process" | "venv", sandbox=True)``) could not run as asked."""


class AnswerTooLargeError(IsolationError):
    """An isolated env's answer would make the parent build far more Python objects than the answer weighs (many
    small containers: a hostile worker's way to exhaust the parent's memory, or an honest one's very large info).
    The parent refused it before building it; the worker goes on. Return numpy arrays rather than many small
    dicts, lists or tuples."""


class EnvCrashedError(IsolationError, EnvCodeError):
    """The worker process running an isolated env died (segfault, kill, memory limit). The message names
    repo@sha, how it died and the last lines of its stderr; ``restart=True`` starts a fresh one on ``reset()``."""


class EnvTimeoutError(IsolationError, EnvCodeError, TimeoutError):
    """A call into an isolated env (``reset``, ``step``, ...) took longer than ``step_timeout``: the worker was killed."""


class RemoteEnvError(EnvCodeError):
    """The env's own code raised inside its worker process. Builtin exception types are re-raised as a class
    that is both this and the original (``except ValueError`` still works); ``__cause__`` holds the remote traceback."""


class SandboxUnavailableError(IsolationError):
    """``sandbox=True`` was asked for, but this machine does not allow a mechanism it needs (the message names it):
    the env was not started (a sandbox never silently runs without one of its parts)."""


class IsolationUnavailableError(IsolationError, NotImplementedError):
    """An isolation option this hub-envs does not implement yet (it is refused, never silently ignored)."""


class VenvBuildError(IsolationError):
    """``isolation="venv"``: uv could not build the env's venv (its message is included); nothing was left behind."""


# --- warnings ---------------------------------------------------------------------------------


class HubEnvsWarning(UserWarning):
    """Base class of every warning hub-envs gives on purpose."""


class UnpinnedRevisionWarning(HubEnvsWarning):
    """load_env was given a branch or tag: the result is pinned to the sha it resolved to, but the call is not."""


class PlainRepoWarning(HubEnvsWarning):
    """load_env loaded a plain LeRobot EnvHub repo (no hub_env.json): the guarantees it cannot give are named."""


class StatesNotRecordedWarning(HubEnvsWarning):
    """The env has ``get_state()`` but what it returns cannot be recorded, so the dataset has no simulator
    states and a replay cannot restore a step (see :mod:`hub_envs.dataset.states`)."""


class RequirementStandInWarning(HubEnvsWarning):
    """A requirement is not installed under its own name, but another installed distribution provides its import
    name (``pygame-ce`` for ``pygame``): the preflight takes it as standing in (see :mod:`hub_envs.repo.requirements`)."""
