"""Who is calling the loopback Hub server and what they may do: tokens to account names, private repos,
direct writes, pushes to pull requests, merges."""

from __future__ import annotations

import hmac

from starlette.requests import Request

from hub_envs.server.httputil import Ctx, HTTPError, require_user
from hub_envs.server.storage import HubStore, Repo, RepoNotFoundError

INVALID_CREDENTIALS = "Invalid credentials in Authorization header"


class Access:
    """The server's accounts and its rules.

    The server's own account (``user``) manages every repo; each other account (``users``) the repos of its own
    namespace. Anyone who can read a repo may open a pull request on it; its author and the repo's managers push
    to it and close it; only managers merge.

    Args:
        store: the repos.
        token: if set, requests must send it (or an account's token) to write or to read private repos; without
            it, every caller without an account's token acts as ``user``.
        user: the server's own account name.
        users: more accounts, ``{token: name}``.
    """

    def __init__(self, store: HubStore, token: str | None, user: str, users: dict[str, str]):
        self.store = store
        self.token = token
        self.user = user
        self.users = users

    def caller(self, request: Request) -> str | None:
        """The account ``request`` acts as, or None (anonymous).

        Args:
            request: the HTTP request; its ``Authorization: Bearer <token>`` names the account.

        Returns:
            The account name, or None for an anonymous caller of a server with a token.

        Raises:
            HTTPError: 401 for a token that is neither the server's nor an account's.
        """
        header = (request.headers.get("authorization") or "").strip()
        for token, name in self.users.items():  # the other accounts, with or without a server token
            if header and hmac.compare_digest(header.encode(), f"Bearer {token}".encode()):
                return name
        if self.token is None:
            return self.user  # open server: everyone else is the server's user
        if not header:
            return None
        if not hmac.compare_digest(header.encode(), f"Bearer {self.token}".encode()):
            raise HTTPError(401, INVALID_CREDENTIALS)
        return self.user

    def open(self, ctx: Ctx, repo_type: str, repo_id: str, write: bool = False) -> Repo:
        """The repo, as ``ctx``'s caller may see it.

        Args:
            ctx: the request.
            repo_type: ``model``, ``dataset`` or ``space``.
            repo_id: ``namespace/name``.
            write: the caller must be authenticated (401 first).

        Returns:
            The repo.

        Raises:
            RepoNotFoundError: no such repo, or a private one and an anonymous caller (as the Hub answers).
            HTTPError: 401 for ``write`` and an anonymous caller.
        """
        if write:
            require_user(ctx)
        repo = self.store.open(repo_type, repo_id)
        if repo.meta.private and not ctx.authenticated:
            raise RepoNotFoundError(f"Repository {repo_id!r} not found.")
        return repo

    def can_manage(self, user: str | None, repo: Repo) -> bool:
        """Whether ``user`` may write to ``repo`` directly, merge or close its pull requests: the server's own
        account manages every repo (a single-user server as before); another account (``users``) its namespace.

        Args:
            user: the account (None: anonymous, who manages nothing).
            repo: the repo.

        Returns:
            True if ``user`` is the server's own account or owns ``repo``'s namespace.
        """
        if user is None:
            return False
        return user == self.user or user.lower() == repo.repo_id.split("/")[0].lower()

    def require_manage(self, ctx: Ctx, repo: Repo, what: str) -> None:
        """403 unless the caller manages ``repo``; ``what`` (``"merge pull requests of"``...) names the attempt.

        Args:
            ctx: the request (its caller).
            repo: the repo.
            what: the attempt, for the message (``"merge pull requests of"``).

        Raises:
            HTTPError: 403, saying to open a pull request instead.
        """
        if not self.can_manage(ctx.user, repo):
            raise HTTPError(
                403,
                f"{ctx.user} cannot {what} {repo.repo_id}: only its owner can. "
                "Open a pull request instead (create_commit(..., create_pr=True)).",
            )

    def require_push(self, ctx: Ctx, repo: Repo, branch: str) -> None:
        """403 unless the caller may commit to ``branch``: a branch needs the repo's owner (:meth:`can_manage`);
        a pull request's ``refs/pr/N`` its owner or the account that opened it (everyone else opens a pull request
        of their own). Checked before any of the body is read.

        Args:
            ctx: the request (its caller).
            repo: the repo committed to.
            branch: a branch name or ``refs/pr/N``.

        Raises:
            HTTPError: 403, naming who may push.
            PullRequestNotFoundError: ``refs/pr/N`` names no pull request.
        """
        if self.can_manage(ctx.user, repo):
            return
        num = branch[len("refs/pr/") :] if branch.startswith("refs/pr/") else ""
        if not (num.isdigit() and len(num) <= 9):
            self.require_manage(ctx, repo, "commit to")
        pr = repo.pull_request(int(num))  # 404 if there is none
        if pr.author != ctx.user:
            raise HTTPError(
                403,
                f"{ctx.user} cannot push to {branch} of {repo.repo_id}: only the pull request's author ({pr.author}) "
                "or the repo's owner can. Open a pull request of your own instead (create_commit(..., create_pr=True)).",
            )


def users_from_env(text: str) -> dict[str, str]:
    """``HUB_ENVS_SERVER_USERS="bob:TOKEN_B,carol:TOKEN_C"`` -> ``{token: name}``: more accounts on this server.

    Args:
        text: the variable's value.

    Returns:
        ``{token: name}``.

    Raises:
        ValueError: an item is not ``name:token``.
    """
    users = {}
    for item in filter(None, (x.strip() for x in text.split(","))):
        name, sep, token = item.partition(":")
        if not sep or not name or not token:
            raise ValueError(f"HUB_ENVS_SERVER_USERS: {item!r} is not 'name:token'.")
        users[token] = name
    return users
