"""The three-way feature check: declared config features vs live rollouts vs the dataset.

For every feature the EnvConfig declares (``features``, keyed by env-side names such as
``agent_pos`` or ``pixels/top``, mapped to LeRobot keys by ``features_map``) it compares

* the declared type and shape,
* what a few seeded random-action steps of the live env produce (and that it lies in the
  observation space, finite), and
* what the bundled dataset's ``meta/info.json`` records for the mapped key,

and also flags live observation keys and dataset keys nobody declared, and an
``info["is_success"]`` that is missing or not a bool. Every disagreement is collected, so the
error shows the whole table rather than the first problem.

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
from hub_envs.errors import EnvCodeError, FeatureMismatchError
from hub_envs.harness.actions import accepts_declared, stored_action, unsupported_reason


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
        header = ("feature", "lerobot key", "declared", "live", "dataset", "verdict")
        body = [
            (r.feature, r.lerobot_key, r.declared, r.live, r.dataset, "ok" if r.ok else "; ".join(r.problems)) for r in self.rows
        ]
        widths = [max(len(str(x)) for x in col) for col in zip(header, *body)]
        widths[-1] = len(header[-1])  # the verdict column is free-form
        line = lambda cells: "  ".join(str(c).ljust(w) for c, w in zip(cells, widths)).rstrip()  # noqa: E731
        return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, body)])

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "steps": self.steps,
            "seed": self.seed,
            "dataset_checked": self.dataset_checked,
            "rows": [r.__dict__ for r in self.rows],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FeatureReport:
        return cls(
            rows=[FeatureRow(**row) for row in data["rows"]],
            steps=int(data["steps"]),
            seed=int(data["seed"]),
            dataset_checked=bool(data["dataset_checked"]),
        )

    def raise_if_mismatch(self, where: str) -> None:
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
    """``steps`` seeded random-action steps; observations include the reset one."""
    try:
        obs, info = env.reset(seed=seed)
    except Exception as e:
        raise EnvCodeError(
            f"{where}: env.reset(seed={seed}) raised {type(e).__name__}: {e}. Fix the env's reset "
            f"(reproduce with env.reset(seed={seed})) and re-publish with push_env."
        ) from e
    env.action_space.seed(seed)
    observations, actions, infos = [obs], [], [info]
    for i in range(steps):
        action = env.action_space.sample()
        try:
            obs, _, terminated, truncated, info = env.step(action)
        except Exception as e:
            raise EnvCodeError(
                f"{where}: env.step at step {i} (seed {seed}) raised {type(e).__name__}: {e}. Fix the env's "
                f"step (reproduce with seeded random actions) and re-publish with push_env."
            ) from e
        actions.append(action)
        observations.append(obs)
        infos.append(info)
        if terminated or truncated:
            obs, info = env.reset()
            observations.append(obs)
            infos.append(info)
    return observations, actions, infos


def check_features(
    cfg, env, dataset_features: dict[str, Any] | None, *, steps: int = 8, seed: int = 0, where: str = "the env"
) -> FeatureReport:
    """Compare declared features, a live seeded rollout of ``env`` and the dataset's info.json features."""
    from lerobot.configs.types import FeatureType

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
    mapped_dataset_keys = set()

    for name, feat in cfg.features.items():
        ftype = feat.type
        declared_shape = tuple(feat.shape)
        key = features_map.get(name)
        problems: list[str] = []
        if key is None:
            problems.append(f"no features_map entry (LeRobot cannot name it; add {name!r}: 'observation.…')")
            key = name
        mapped_dataset_keys.add(key)
        # -- live --
        if ftype == FeatureType.ACTION:
            space = env.action_space
            shape = tuple(space.shape or ())
            dtype = np.asarray(actions[0]).dtype if actions else getattr(space, "dtype", "?")
            live = f"{dtype} {shape}"
            unsupported = unsupported_reason(space)
            if unsupported:
                problems.append(unsupported)
            elif not accepts_declared(space, declared_shape):
                problems.append(f"action_space shape {shape} != declared {declared_shape}")
        else:
            try:
                values = [np.asarray(_lookup(o, name)) for o in observations]
            except KeyError:
                values = []
            live_keys.discard(name)
            if not values:
                live = "missing"
                problems.append(f"observation has no key {name!r} (it has {sorted(_flat_keys(observations[0]))})")
            else:
                live = _describe(values[0])
                if tuple(values[0].shape) != declared_shape:
                    problems.append(f"live shape {tuple(values[0].shape)} != declared {declared_shape}")
                if ftype == FeatureType.VISUAL:
                    if values[0].dtype != np.uint8 or values[0].ndim != 3 or values[0].shape[-1] not in (1, 3, 4):
                        problems.append(f"VISUAL feature must be a uint8 (H, W, C) image, live is {live}")
                elif not np.issubdtype(values[0].dtype, np.floating):
                    problems.append(f"{_type_name(ftype)} feature must be floating point, live is {values[0].dtype}")
                else:
                    bad = [i for i, v in enumerate(values) if not np.all(np.isfinite(v))]
                    if bad:
                        problems.append(f"non-finite values (NaN/inf) at step {bad[0]}")
                space = _space_for(env.observation_space, name)
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
        # -- dataset --
        if dataset_features is None:
            dataset = "-"
        elif key not in dataset_features:
            dataset = "missing"
            problems.append(f"dataset has no feature {key!r}")
        else:
            spec = dataset_features[key]
            ds_shape = tuple(spec.get("shape", ()))
            ds_dtype = spec.get("dtype", "?")
            dataset = f"{ds_dtype} {ds_shape}"
            if ftype == FeatureType.ACTION and unsupported_reason(env.action_space) is None:
                want_shape, want_dtype = stored_action(env.action_space)
                if ds_shape != want_shape or (declared_shape not in (want_shape, ()) and ds_shape != declared_shape):
                    problems.append(f"dataset shape {ds_shape} != declared {declared_shape} (stored as {want_shape})")
                if ds_dtype != want_dtype:
                    problems.append(f"dataset dtype {ds_dtype} != {want_dtype}, which the live {dtype} actions are stored as")
            else:
                if ds_shape != declared_shape:
                    problems.append(f"dataset shape {ds_shape} != declared {declared_shape}")
                if ftype == FeatureType.VISUAL and ds_dtype not in ("image", "video"):
                    problems.append(f"dataset dtype {ds_dtype!r} for a VISUAL feature (expected 'image' or 'video')")
                if ftype != FeatureType.VISUAL and ds_dtype not in ("float32", "float64"):
                    problems.append(f"dataset dtype {ds_dtype!r} for a {_type_name(ftype)} feature (expected float32)")
        rows.append(FeatureRow(name, key, f"{_type_name(ftype)} {declared_shape}", live, dataset, problems))

    for extra in sorted(live_keys):
        value = np.asarray(_lookup(observations[0], extra))
        rows.append(
            FeatureRow(
                extra,
                features_map.get(extra, "-"),
                "-",
                _describe(value),
                "-",
                [f"observation key {extra!r} is not declared in config.features"],
            )
        )
    if dataset_features is not None:
        for extra in sorted(set(dataset_features) - mapped_dataset_keys - BOOKKEEPING_KEYS):
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

    bad_success = [i for i, info in enumerate(infos) if not isinstance(info.get("is_success"), (bool, np.bool_))]
    success_problems = []
    if bad_success:
        i = bad_success[0]
        got = infos[i].get("is_success", "missing")
        success_problems.append(
            f"info['is_success'] must be a bool in every reset/step info; got {got!r} ({type(got).__name__}) at call {i}"
        )
    rows.append(
        FeatureRow(
            "info.is_success",
            "next.success",
            "bool",
            "bool" if not bad_success else "wrong",
            "-" if dataset_features is None else ("bool" if "next.success" in dataset_features else "missing"),
            success_problems,
        )
    )
    return FeatureReport(rows=rows, steps=steps, seed=seed, dataset_checked=dataset_features is not None)
