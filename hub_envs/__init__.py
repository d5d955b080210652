"""hub-envs."""
