"""LeRobot's dataset format, as hub-envs writes and reads it (no lerobot or torch needed to read).

- :mod:`~hub_envs.dataset.layout`: paths, path templates and bookkeeping keys (one place for each).
- :mod:`~hub_envs.dataset.writer`: the fast, byte-deterministic writer of rollouts.
- :mod:`~hub_envs.dataset.reader`: the one reader (info, episodes metadata, frames, fingerprint).
- :mod:`~hub_envs.dataset.codec`: PNG, the one image codec.
- :mod:`~hub_envs.dataset.png_process`: camera episodes PNG-encoded in a helper process while the next are made.
- :mod:`~hub_envs.dataset.stats`: LeRobot-shaped stats, computed exactly.
- :mod:`~hub_envs.dataset.states`: simulator states recorded beside the data.

It depends only on :mod:`hub_envs.errors` and :mod:`hub_envs._compat`; everything above it may use it.
"""
