"""The three-way feature check: the features the EnvConfig declares vs what the live env produces vs what the dataset
records, every disagreement collected in one table.

Example:
    >>> from hub_envs.harness.features import check_features                     # doctest: +SKIP
    >>> report = check_features(cfg, env, dataset_features=None)          # doctest: +SKIP
    >>> print(report.table())                                             # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hub_envs.dataset.layout import BOOKKEEPING_KEYS
from hub_envs.errors import FeatureMismatchError
from hub_envs.harness.actions import accepts_declared, stored_action, unsupported_reason
from hub_envs.harness.episode import SeededEpisode


@dataclass
class FeatureRow:
    feature: str
    lerobot_key: str
    declared: str
    live: str
    dataset: str
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


@dataclass
class FeatureReport:
    rows: list[FeatureRow]
    steps: int
    seed: int
    dataset_checked: bool

    @property
    def ok(self) -> bool:
        return all(r.ok for r in self.rows)

    @property
    def mismatches(self) -> list[FeatureRow]:
        return [r for r in self.rows if not r.ok]

    def table(self) -> str:
        """The report as a text table: feature, LeRobot key, declared, live, dataset, verdict."""
        header = ("feature", "lerobot key", "declared", "live", "dataset", "verdict")
        body = [
            (r.feature, r.lerobot_key, r.declared, r.live, r.dataset, "ok" if r.ok else "; ".join(r.problems)) for r in self.rows
        ]
        widths = [max(len(str(x)) for x in col) for col in zip(header, *body)]
        widths[-1] = len(header[-1])  # the verdict column is free-form
        line = lambda cells: "  ".join(str(c).ljust(w) for c, w in zip(cells, widths)).rstrip()  # noqa: E731
        return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, body)])

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready data (the check cache stores it)."""
        return {
            "ok": self.ok,
            "steps": self.steps,
            "seed": self.seed,
            "dataset_checked": self.dataset_checked,
            "rows": [r.__dict__ for r in self.rows],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FeatureReport:
        """The report :meth:`to_dict` wrote.

        Args:
            data: :meth:`to_dict`'s output.

        Returns:
            The :class:`FeatureReport`.
        """
        return cls(
            rows=[FeatureRow(**row) for row in data["rows"]],
            steps=int(data["steps"]),
            seed=int(data["seed"]),
            dataset_checked=bool(data["dataset_checked"]),
        )

    def raise_if_mismatch(self, where: str) -> None:
        """Raise when a row disagrees.

        Args:
            where: names the env in the message.

        Raises:
            FeatureMismatchError: with the whole table, and the mismatches.
        """
        if self.ok:
            return
        n = len(self.mismatches)
        raise FeatureMismatchError(
            f"{where}: {n} feature(s) disagree between the config's declared features, the live env"
            f"{' and the dataset' if self.dataset_checked else ''}:\n{self.table()}\n"
            f"Fix the EnvConfig's features/features_map (or the env), then re-publish with push_env.",
            mismatches=self.mismatches,
            table=self.table(),
        )


def _describe(value: Any) -> str:
    arr = np.asarray(value)
    return f"{arr.dtype} {tuple(arr.shape)}"


def _lookup(obs: Any, key: str) -> Any:
    node = obs
    for part in key.split("/"):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(key)
        node = node[part]
    return node


def _flat_keys(obs: Any, prefix: str = "") -> list[str]:
    if isinstance(obs, dict):
        out = []
        for k, v in obs.items():
            out += _flat_keys(v, f"{prefix}{k}/")
        return out
    return [prefix[:-1]]


def _space_for(space: Any, key: str) -> Any:
    node = space
    for part in key.split("/"):
        node = node.spaces[part] if hasattr(node, "spaces") and part in node.spaces else None
        if node is None:
            return None
    return node


def _type_name(ftype: Any) -> str:
    return getattr(ftype, "value", str(ftype))


def _rollout(env, steps: int, seed: int, where: str = "the env") -> tuple[list[Any], list[Any], list[dict]]:
    """``steps`` seeded random-action steps, across episode ends (episode ``k`` resets with ``seed + k``);
    observations and infos include every reset's."""
    observations: list[Any] = []
    actions: list[Any] = []
    infos: list[dict] = []
    episode, k = None, -1
    for _ in range(steps):
        if episode is None or episode.done:
            k += 1
            episode = SeededEpisode(env, seed + k, where=f"{where}, seed {seed + k}")
            observations.append(episode.obs)
            infos.append(episode.info)
        action = episode.sample()
        obs, _, _, _, info = episode.step(action)
        actions.append(action)
        observations.append(obs)
        infos.append(info)
    return observations, actions, infos


def _live_action(space: Any, declared: tuple[int, ...], actions: list[Any]) -> tuple[str, list[str]]:
    """What the live env's action space is (its description) and what is wrong with it for ``declared``."""
    shape = tuple(space.shape or ())
    dtype = np.asarray(actions[0]).dtype if actions else getattr(space, "dtype", "?")
    unsupported = unsupported_reason(space)
    if unsupported:
        return f"{dtype} {shape}", [unsupported]
    if not accepts_declared(space, declared):
        return f"{dtype} {shape}", [f"action_space shape {shape} != declared {declared}"]
    return f"{dtype} {shape}", []


def _live_observation(
    name: str, ftype: Any, declared: tuple[int, ...], observations: list[Any], obs_space: Any
) -> tuple[str, list[str]]:
    """One observation feature across the live steps: its description and what is wrong with it."""
    from lerobot.configs.types import FeatureType  # heavy: lerobot (torch)

    try:
        values = [np.asarray(_lookup(o, name)) for o in observations]
    except KeyError:
        return "missing", [f"observation has no key {name!r} (it has {sorted(_flat_keys(observations[0]))})"]
    live = _describe(values[0])
    problems = []
    if tuple(values[0].shape) != declared:
        problems.append(f"live shape {tuple(values[0].shape)} != declared {declared}")
    if ftype == FeatureType.VISUAL:
        if values[0].dtype != np.uint8 or values[0].ndim != 3 or values[0].shape[-1] not in (1, 3, 4):
            problems.append(f"VISUAL feature must be a uint8 (H, W, C) image, live is {live}")
    elif not np.issubdtype(values[0].dtype, np.floating):
        problems.append(f"{_type_name(ftype)} feature must be floating point, live is {values[0].dtype}")
    else:
        bad = [i for i, v in enumerate(values) if not np.all(np.isfinite(v))]
        if bad:
            problems.append(f"non-finite values (NaN/inf) at step {bad[0]}")
    space = _space_for(obs_space, name)
    if space is None:
        problems.append(f"observation_space has no entry {name!r}")
    else:
        outside = [i for i, v in enumerate(values) if not space.contains(v)]
        if outside and not any("non-finite" in p for p in problems):
            v = values[outside[0]]
            problems.append(
                f"outside observation_space at step {outside[0]} (min {v.min():.4g}, max {v.max():.4g})"
                if v.size and v.shape == space.shape
                else f"outside observation_space at step {outside[0]}"
            )
    return live, problems


def _in_dataset(
    key: str, ftype: Any, declared: tuple[int, ...], dataset_features: dict[str, Any] | None, action_space: Any
) -> tuple[str, list[str]]:
    """One feature as the dataset's info.json declares it: its description and what is wrong with it."""
    from lerobot.configs.types import FeatureType  # heavy: lerobot (torch)

    if dataset_features is None:
        return "-", []
    if key not in dataset_features:
        return "missing", [f"dataset has no feature {key!r}"]
    spec = dataset_features[key]
    ds_shape, ds_dtype = tuple(spec.get("shape", ())), spec.get("dtype", "?")
    problems = []
    if ftype == FeatureType.ACTION and unsupported_reason(action_space) is None:
        want_shape, want_dtype = stored_action(action_space)
        if ds_shape != want_shape or (declared not in (want_shape, ()) and ds_shape != declared):
            problems.append(f"dataset shape {ds_shape} != declared {declared} (stored as {want_shape})")
        if ds_dtype != want_dtype:
            problems.append(f"dataset dtype {ds_dtype} != {want_dtype}, which the live actions are stored as")
    else:
        if ds_shape != declared:
            problems.append(f"dataset shape {ds_shape} != declared {declared}")
        if ftype == FeatureType.VISUAL and ds_dtype not in ("image", "video"):
            problems.append(f"dataset dtype {ds_dtype!r} for a VISUAL feature (expected 'image' or 'video')")
        if ftype != FeatureType.VISUAL and ds_dtype not in ("float32", "float64"):
            problems.append(f"dataset dtype {ds_dtype!r} for a {_type_name(ftype)} feature (expected float32)")
    return f"{ds_dtype} {ds_shape}", problems


def _undeclared(
    observations: list[Any], live_keys: set[str], features_map: dict, dataset_features: dict | None, mapped: set
) -> list[FeatureRow]:
    """Rows for what the env observes or the dataset holds that the config does not declare."""
    rows = [
        FeatureRow(
            extra,
            features_map.get(extra, "-"),
            "-",
            _describe(np.asarray(_lookup(observations[0], extra))),
            "-",
            [f"observation key {extra!r} is not declared in config.features"],
        )
        for extra in sorted(live_keys)
    ]
    for extra in sorted(set(dataset_features or {}) - mapped - BOOKKEEPING_KEYS):
        spec = dataset_features[extra]
        rows.append(
            FeatureRow(
                "-",
                extra,
                "-",
                "-",
                f"{spec.get('dtype')} {tuple(spec.get('shape', ()))}",
                [f"dataset feature {extra!r} is not declared in config.features"],
            )
        )
    return rows


def _success_row(infos: list[dict], dataset_features: dict | None) -> FeatureRow:
    """``info["is_success"]``: a bool at every reset and step (LeRobot's eval reads it), ``next.success`` in the data."""
    bad = [i for i, info in enumerate(infos) if not isinstance(info.get("is_success"), (bool, np.bool_))]
    problems = []
    if bad:
        got = infos[bad[0]].get("is_success", "missing")
        problems.append(
            f"info['is_success'] must be a bool in every reset/step info; got {got!r} ({type(got).__name__}) at call {bad[0]}"
        )
    dataset = "-" if dataset_features is None else ("bool" if "next.success" in dataset_features else "missing")
    return FeatureRow("info.is_success", "next.success", "bool", "bool" if not bad else "wrong", dataset, problems)


def check_features(
    cfg, env, dataset_features: dict[str, Any] | None, *, steps: int = 8, seed: int = 0, where: str = "the env"
) -> FeatureReport:
    """Compare the features the config declares with a live seeded rollout of ``env`` and the dataset's ``info.json``.

    One row per declared feature (:func:`_live_action` or :func:`_live_observation`, then :func:`_in_dataset`), rows for
    what is not declared (:func:`_undeclared`), and the success flag (:func:`_success_row`).

    Args:
        cfg: the env's config (``features``, ``features_map``).
        env: a live env (reset with ``seed``, stepped ``steps`` times with seeded random actions).
        dataset_features: the dataset's ``info.json`` ``features`` (None: no dataset half).
        steps: random-action steps.
        seed: the reset seed.
        where: names the env in messages.

    Returns:
        The :class:`FeatureReport` (:meth:`FeatureReport.raise_if_mismatch` refuses a disagreement).

    Raises:
        EnvCodeError: the env raised while stepping.
    """
    from lerobot.configs.types import FeatureType  # heavy: lerobot (torch)

    observations, actions, infos = _rollout(env, steps, seed, where)
    features_map = dict(getattr(cfg, "features_map", {}) or {})
    rows: list[FeatureRow] = []
    live_keys = set(_flat_keys(observations[0])) if isinstance(observations[0], dict) else set()
    if not isinstance(observations[0], dict):
        rows.append(
            FeatureRow(
                "(observation)",
                "-",
                "dict",
                _describe(observations[0]),
                "-",
                ["observations must be dicts such as {'agent_pos': ...} (LeRobot's format)"],
            )
        )
    mapped: set[str] = set()
    for name, feat in cfg.features.items():
        declared = tuple(feat.shape)
        key = features_map.get(name)
        problems: list[str] = []
        if key is None:
            problems.append(f"no features_map entry (LeRobot cannot name it; add {name!r}: 'observation.…')")
            key = name
        mapped.add(key)
        if feat.type == FeatureType.ACTION:
            live, live_problems = _live_action(env.action_space, declared, actions)
        else:
            live_keys.discard(name)
            live, live_problems = _live_observation(name, feat.type, declared, observations, env.observation_space)
        dataset, dataset_problems = _in_dataset(key, feat.type, declared, dataset_features, env.action_space)
        rows.append(
            FeatureRow(
                name, key, f"{_type_name(feat.type)} {declared}", live, dataset, problems + live_problems + dataset_problems
            )
        )
    rows += _undeclared(observations, live_keys, features_map, dataset_features, mapped)
    rows.append(_success_row(infos, dataset_features))
    return FeatureReport(rows=rows, steps=steps, seed=seed, dataset_checked=dataset_features is not None)
