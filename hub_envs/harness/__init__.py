"""The harness: run an env's episodes and judge what comes out.

- :mod:`~hub_envs.harness.rollout`: the episode engine (seeded episodes, recorded; worker processes).
- :mod:`~hub_envs.harness.features`: the three-way feature check (declared vs live vs dataset).
- :mod:`~hub_envs.harness.checks`: gymnasium's checker, determinism, the golden-rollout fingerprint.
- :mod:`~hub_envs.harness.replay`: replay a dataset's actions and compare every step.
- :mod:`~hub_envs.harness.benchmark`: re-run declared benchmark results, with bootstrap CIs.
- :mod:`~hub_envs.harness.report`: the reproduction report (JSON, Markdown, PNG).
- :mod:`~hub_envs.harness.provenance`: the versions a result depends on.
- :mod:`~hub_envs.harness.media`: the card's rollout GIF.

It uses :mod:`hub_envs.dataset` and the repo format below it, never the operations above it
(load, push, reproduce), which pass it envs and folders.
"""
