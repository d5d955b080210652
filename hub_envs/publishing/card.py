"""The env card (README.md), rendered from ``hub_envs/templates/env_card.md.j2`` with huggingface_hub's ModelCard.

The YAML header is a :class:`huggingface_hub.ModelCardData`: tags, ``library_name``, and the
random-policy benchmark as model-index evaluation results, so the Hub shows it as metadata.

Example:
    >>> from hub_envs.publishing.card import template_path
    >>> template_path().name
    'env_card.md.j2'
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from huggingface_hub import EvalResult, ModelCard, ModelCardData

from hub_envs.errors import InvalidRepoFormatError
from hub_envs.harness.media import MEDIA_EPISODES
from hub_envs.paths import PACKAGE_DIR
from hub_envs.repo.format import GIF_FILE, MP4_FILE, Manifest

TAGS = ["lerobot", "gymnasium", "robotics", "hub-envs", "reinforcement-learning"]


def template_path(name: str = "env_card.md.j2") -> Path:
    """The path of a card template (package data).

    Args:
        name: the template's file name.

    Returns:
        Its path.

    Raises:
        InvalidRepoFormatError: the template is missing (an incomplete install).
    """
    path = PACKAGE_DIR / "templates" / name  # package data: the wheel carries it
    if not path.is_file():
        raise InvalidRepoFormatError(f"Card template {path} is missing: this hub-envs install is incomplete. Reinstall hub-envs.")
    return path


def env_documentation(env_class: type) -> str:
    """What the card says of the env.

    Args:
        env_class: the env's class.

    Returns:
        Its module's docstring (reward, termination, success), else the class's.
    """
    module = inspect.getmodule(env_class)
    doc = inspect.getdoc(module) if module is not None else None
    return doc or inspect.getdoc(env_class) or "(The env's module has no docstring.)"


def success_description(doc: str) -> str:
    """The docstring paragraph (or bullet) that defines ``is_success``, as one plain line.

    Args:
        doc: the env's documentation (:func:`env_documentation`).

    Returns:
        The line, or a pointer to the description below.
    """
    blocks, current = [], []
    for line in doc.splitlines():
        starts_bullet = line.lstrip().startswith(("* ", "- "))
        if not line.strip() or (starts_bullet and current):
            if current:
                blocks.append(" ".join(current))
            current = []
        if line.strip():
            current.append(line.strip())
    if current:
        blocks.append(" ".join(current))
    for block in blocks:
        if "is_success" in block or "success" in block.lower():
            text = re.sub(r"^[-*]\s+", "", block)
            text = re.sub(r"^\*\*[^*]+\*\*:?\s*", "", text)  # a bold label such as **Success**
            return text.replace("``", "`")
    return "see the environment description below"


def describe_space(space) -> str:
    """A compact one-line description of a gymnasium space (Box bounds summarized, not listed).

    Args:
        space: a gymnasium space.

    Returns:
        The line.
    """
    if isinstance(space, spaces.Dict):
        return "Dict(" + ", ".join(f"{k}: {describe_space(v)}" for k, v in space.spaces.items()) + ")"
    if isinstance(space, spaces.Box):
        low, high = np.min(space.low), np.max(space.high)
        bounds = (
            f"[{low:.4g}, {high:.4g}]"
            if np.all(space.low == low) and np.all(space.high == high)
            else f" within [{low:.4g}, {high:.4g}]"
        )
        return f"Box{bounds} shape {tuple(space.shape)} {space.dtype}"
    return str(space)


#: What a "Reproduced on" cell may show of an attestation's free-text fields (versions, CPU, platform, an account):
#: letters, digits and a few separators; no Markdown or HTML syntax, no backtick, no '|', no line break.
_CELL_UNSAFE = re.compile(r"[^A-Za-z0-9 .,:;/@()+=_-]")
_CELL_MAX = 60


def _cell(value) -> str:
    """A field an attestation's author wrote, as one inert table cell: whitelisted characters (any other becomes
    ``?``), one line, at most 60 characters, inside a code span (so no link, emphasis or HTML is rendered).

    >>> _cell("3.2.7"), _cell("0.6 |\\n\\n## Load it"), _cell("")
    ('`3.2.7`', '`0.6 ? ?? Load it`', '-')
    """
    text = _CELL_UNSAFE.sub("?", " ".join(str(value).split()))
    text = text if len(text) <= _CELL_MAX else text[: _CELL_MAX - 1] + "…"
    return f"`{text}`" if text.strip() else "-"


#: What an env's own text (its task, a task's instruction) may not bring into the card as Markdown: every character
#: CommonMark or GFM gives a meaning inside a line (emphasis, code, links, images, HTML, table cells), backslash-escaped.
_MARKDOWN_INLINE = re.compile(r"([\\`*_\[\]<>!&|~])")
_ENV_TEXT_MAX = 200


def _one_line(value: Any) -> str:
    """``value`` as one line of printable text (control, bidi and line-break characters become spaces), at most 200
    characters."""
    text = " ".join("".join(c if c.isprintable() else " " for c in str(value)).split())
    return text if len(text) <= _ENV_TEXT_MAX else text[: _ENV_TEXT_MAX - 1] + "…"


def env_text(value: Any) -> str:
    """Text an env's code chose (a task instruction) as inert Markdown on one line: what it says, nothing it could make
    the card do (no heading, code block, link, HTML or extra table cell: adopt renders another author's env into your card).

    Args:
        value: the text.

    Returns:
        The escaped text (``-`` for none).

    >>> env_text("reach the left target"), env_text("x |\\n\\n## Load it <img src=x>")
    ('reach the left target', 'x \\\\| ## Load it \\\\<img src=x\\\\>')
    """
    text = _one_line(value) if value is not None else ""
    return _MARKDOWN_INLINE.sub(r"\\\1", text) if text.strip() else "-"


def env_span(value: Any, *, table: bool = True) -> str:
    """An env's name for something (its task) as one inert code span: one line, fenced with more backticks than it holds,
    ``|`` escaped in a table cell (GFM splits cells before code spans).

    Args:
        value: the text.
        table: whether the span sits in a table cell.

    Returns:
        The code span (``-`` for none).

    >>> env_span("reach-left"), env_span("a`b |\\n## x")
    ('`reach-left`', '``a`b \\\\| ## x``')
    """
    text = _one_line(value) if value is not None else ""
    if not text.strip():
        return "-"
    fence = "`" * (max((len(run) for run in re.findall(r"`+", text)), default=0) + 1)
    pad = " " if text[0] == "`" or text[-1] == "`" else ""
    return f"{fence}{pad}{text.replace('|', chr(92) + '|') if table else text}{pad}{fence}"


def reproduced_table(entries) -> str:
    """The card's "Reproduced on" table: one row per merged attestation (:class:`hub_envs.repo.attestations.AttestationEntry`
    with a valid attestation), oldest first; "" without any.

    Every field the attestation's author wrote goes through :func:`_cell`; the rest is validated (dates, hex shas,
    the verdict). "by" is the account that opened the merged pull request (the Hub's discussion data), never the
    file's self-declared ``attested_by``; "signature" says whether the claim is signed (a card cannot check a key:
    ``hub-envs attestations --verify=true`` does).

    >>> reproduced_table([])
    ''
    """
    rows = sorted(entries, key=lambda e: (e.attestation.created_at, e.attestation.stack_digest, e.path))
    if not rows:
        return ""
    out = [
        "| date | verdict | commit | stack | python | lerobot | torch | numpy | gymnasium | simulator | platform / CPU | by "
        "| signature |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for e in rows:
        a = e.attestation
        pk = a.stack.get("packages", {})
        pk = pk if isinstance(pk, dict) else {}
        sim = a.stack.get("simulator", {})
        sim = ", ".join(f"{k} {v}" for k, v in sorted(sim.items())) if isinstance(sim, dict) else str(sim)
        system = f"{str(a.stack.get('platform', '-')).split('-')[0]} {a.stack.get('machine', '')}, {a.stack.get('cpu', '-')}"
        by = "no pull request" if e.author is None else _cell(f"@{e.author}")
        by += f" (PR #{e.merged_from})" if e.author is not None and e.merged_from is not None else ""
        done, of = a.tasks_reproduced
        cells = [
            _cell(a.created_at[:10]),
            f"{'✓ ' if a.reproduced else '✗ '}{a.verdict.lower()}" + (f", {done} of {of} tasks" if of else ""),
            f"`{a.sha[:12]}`",
            _cell(a.stack_digest),
            _cell(a.stack.get("python", "-")),
            *(_cell(pk.get(n, "-")) for n in ("lerobot", "torch", "numpy", "gymnasium")),
            _cell(sim or "-"),
            _cell(system),
            by,
            "signed (OpenSSH)" if e.signed else "**unsigned**",
        ]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out + _tasks_table(rows))


def _tasks_table(rows) -> list[str]:
    """A suite's attestations per task: one row per task, one column per attestation that names its tasks (its date,
    commit and stack), each cell ✓ or ✗; nothing when none does (a one-task env's table stays as it was)."""
    suites = [e for e in rows if e.attestation.tasks]
    if not suites:
        return []
    names = list(dict.fromkeys(str(t["task"]) for e in suites for t in e.attestation.tasks))
    header = [
        f"{_cell(e.attestation.created_at[:10])} `{e.attestation.sha[:12]}` {_cell(e.attestation.stack_digest)}" for e in suites
    ]
    out = ["", "Per task (a benchmark suite's verdict for each of its tasks):", "", "| task | " + " | ".join(header) + " |"]
    out.append("|---|" + "---|" * len(suites))
    for name in names:
        marks = []
        for e in suites:
            t = next((t for t in e.attestation.tasks if t["task"] == name), None)
            marks.append("–" if t is None else "✓" if t["reproduced"] else "✗")
        out.append(f"| {_cell(name)} | " + " | ".join(marks) + " |")
    return out


def media_note(seeds: list, fps: Any, media_kwargs: Mapping[str, Any]) -> str:
    """What the card says under its GIF: which episodes, at what speed, rendered how (enough to render it again).

    >>> media_note([0, 1, 2, 3], 30, {"render_camera": {"target": "drone"}, "render_width": 256})
    ": episodes of seeds 0, 1, 2, real time (30 fps), from `env.render()` of `make(render_camera={'target': 'drone'}, render_width=256)`"
    """
    shown = ", ".join(str(s) for s in seeds[:MEDIA_EPISODES])
    how = ", ".join(f"{k}={v!r}" for k, v in media_kwargs.items()).replace("`", "'")
    return f": episodes of seeds {shown}, real time ({fps} fps), from `env.render()` of `make({how})`"


def render_card(
    manifest: Manifest,
    *,
    env_class: type,
    env,
    content_tag: str,
    media_kwargs: Mapping[str, Any] | None = None,
    license: str | None = None,
    reproductions: list | tuple = (),
    dataset_repo: bool = False,
) -> str:
    """Render the card (``README.md``) of a repo about to be published, from its manifest (``files`` not final yet: the
    card is one of them).

    Args:
        manifest: the manifest, with its content digest.
        env_class: the env's class (its documentation).
        env: a live env (the spaces shown).
        content_tag: the content tag the card's load line pins.
        license: what the env folder's pyproject declares (an SPDX id); None: the card claims none.
        reproductions: merged attestations (:class:`hub_envs.repo.attestations.AttestationEntry`, valid ones); those of
            this content (its digest) make the "Reproduced on" table.
        dataset_repo: the dataset is also published as the dataset repo of the same name: the card says how LeRobot
            opens it by repo id, and its metadata links that dataset (``datasets:``).
        media_kwargs: what the GIF's env was made with (:func:`hub_envs.harness.media.card_media_kwargs`), stated
            under it.

    Returns:
        The card's text.

    Raises:
        InvalidRepoFormatError: the card template is missing.
    """
    repo_id = manifest.repo_id
    config = manifest.config
    dataset = manifest.dataset
    ds_features = dataset.get("features", {})
    features = []
    for name, feat in config.get("features", {}).items():
        key = config.get("features_map", {}).get(name, name)
        features.append(
            {
                "name": name,
                "type": feat["type"],
                "shape": tuple(feat["shape"]),
                "key": key,
                "dtype": ds_features.get(key, {}).get("dtype", "-"),
            }
        )
    benchmarks = list(manifest.benchmarks)
    eval_results = [
        EvalResult(
            task_type="reinforcement-learning",
            task_name="reinforcement-learning",
            dataset_type=repo_id,
            dataset_name=manifest.name,
            metric_type=metric,
            metric_name=f"{metric} ({b['policy']['type']} policy{', task ' + b['task'] if b.get('task') else ''})",
            metric_value=float(value),
            verified=False,
        )
        for b in benchmarks
        for metric, value in b["metrics"].items()
    ]
    card_data = ModelCardData(
        library_name="hub-envs",
        tags=TAGS + [manifest.name],
        model_name=repo_id,
        eval_results=eval_results or None,
        license=license,
        datasets=[repo_id] if dataset_repo else None,
    )
    doc = env_documentation(env_class)
    seeds = dataset.get("seeds", [])
    seeds_text = f"{seeds[0]}…{seeds[-1]} ({len(seeds)})" if len(seeds) > 3 else ", ".join(map(str, seeds))
    card = ModelCard.from_template(
        card_data,
        template_path=str(template_path()),
        title=f"{manifest.name} — a hub-envs environment",
        description=manifest.description or "A gymnasium environment in LeRobot's format, shared with hub-envs.",
        gif_path=GIF_FILE,
        gif_caption="Random-action rollouts",
        gif_note=media_note(seeds, config.get("fps"), media_kwargs or {}),
        mp4_path=MP4_FILE if any(ft.get("dtype") == "video" for ft in ds_features.values()) else None,
        repo_id=repo_id,
        content_tag=content_tag,
        content_digest=manifest.content_digest,
        task=config.get("task"),
        span=env_span,  # an env's own text goes into the card inert (adopt renders another author's env)
        text=env_text,
        fps=config.get("fps"),
        episode_length=config.get("episode_length"),
        config_overrides=manifest.config_overrides,
        requirements_text=", ".join(f"`{r}`" for r in manifest.requirements) or "none beyond hub-envs",
        features=features,
        observation_space=describe_space(env.observation_space),
        action_space=describe_space(env.action_space),
        success_text=success_description(doc),
        env_doc=doc,
        dataset=dataset,
        dataset_repo=dataset_repo,
        seeds_text=seeds_text,
        benchmarks=benchmarks,
        tasks=task_rows(manifest),
        suite_name=manifest.name,
        fingerprint_digest=manifest.fingerprint.get("digest", "-"),
        versions=manifest.versions,
        processors=list(manifest.processors),
        reproduced_table=reproduced_table([e for e in reproductions if e.attestation.content_digest == manifest.content_digest]),
    )
    return str(card)


def task_rows(manifest: Manifest) -> list[dict[str, Any]]:
    """A suite's per-task table: each task's id, name, instruction, episodes, seeds, random-policy results, fingerprint.

    Args:
        manifest: the manifest (its ``tasks`` and per-task ``benchmarks``).

    Returns:
        One row per task, in task-id order (``[]`` for a one-task env).
    """
    by_task = {b.get("task"): b for b in manifest.benchmarks if b.get("name") == "random-policy"}
    rows = []
    for t in manifest.tasks:
        seeds, metrics = t["seeds"], by_task.get(t["task"], {}).get("metrics", {})
        rows.append(
            {
                "id": t["task_index"],
                "task": t["task"],
                "instruction": t["instruction"],
                "episodes": f"{t['episodes'][0]}…{t['episodes'][-1]}" if len(t["episodes"]) > 1 else t["episodes"],
                "seeds": f"{seeds[0]}…{seeds[-1]}" if len(seeds) > 1 else seeds,
                "mean_return": metrics.get("mean_return", float("nan")),
                "success_rate": metrics.get("success_rate", float("nan")),
                "fingerprint": str(t.get("fingerprint", {}).get("digest", "-"))[:16],
            }
        )
    return rows
