"""The name every published ``env.py`` imports for the endpoint check (hub_envs/templates/env_entry.py): Hub I/O
is :mod:`hub_envs.repo.hub_io`."""

from hub_envs.repo import hub_io  # noqa: F401  (importing it installs the endpoint check)
