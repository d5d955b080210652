"""An env's code: importing it under a name unique to repo@sha, its real-file copy, its EnvConfig, its registration."""
