"""The artifact and its transport: the env repo format, Hub I/O, the trust list, requirements, attestations."""
