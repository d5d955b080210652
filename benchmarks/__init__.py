"""Benchmarks of hub-envs (``make bench``): each module has ``run() -> dict``; :mod:`benchmarks.run` collects them."""
