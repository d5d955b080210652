"""``python -m hub_envs.cli``: the ``hub-envs`` command."""

import sys

from hub_envs.cli import main

sys.exit(main())
