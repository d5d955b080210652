"""Benchmark suites: one env folder declaring several tasks (``[tool.hub-envs] tasks``), published by one push as one
repo (one dataset of every task, per-task benchmarks and fingerprints, a per-task card table), loaded one task at a time
or whole, given to LeRobot in its ``{suite: {task id: VectorEnv}}`` form (its own EnvHub loader, ``--env.type=hub``,
its unmodified ``lerobot-eval``), and reproduced per task.

Real parts only: the loopback Hub server, huggingface_hub, LeRobot's make_env / draccus parsing / lerobot-eval /
LeRobotDataset, gymnasium, torch on the CPU.
"""

from __future__ import annotations

import json
import subprocess
import sys
import urllib.request
from pathlib import Path

import draccus
import numpy as np
import pandas as pd
import pytest
from helpers import FIXTURES, TINY, copy_env
from lerobot.configs.eval import EvalPipelineConfig

from hub_envs import errors, load_env, push_env
from hub_envs.cli import main as cli_main
from hub_envs.repo.format import EnvFolder

SUITE = FIXTURES / "suite_env"
TASKS = ["reach-left", "reach-center", "reach-right"]
TARGETS = {"reach-left": -0.5, "reach-center": 0.0, "reach-right": 0.5}
INSTRUCTIONS = {
    "reach-left": "move the point to the left target",
    "reach-center": "move the point to the middle",
    "reach-right": "move the point to the right target",
}
EPISODES = 2  # per task

#: A tiny ACT (state and environment state in, no image): seconds on a CPU.
TINY_ACT = [
    "--policy.type=act",
    "--policy.push_to_hub=false",
    "--policy.device=cpu",
    "--policy.dim_model=16",
    "--policy.n_heads=2",
    "--policy.dim_feedforward=32",
    "--policy.n_encoder_layers=1",
    "--policy.n_decoder_layers=1",
    "--policy.chunk_size=5",
    "--policy.n_action_steps=5",
    "--policy.use_vae=false",
    "--policy.pretrained_backbone_weights=null",
]


@pytest.fixture(scope="module")
def suite(hub_module):
    """The three-task fixture suite, pushed once: its PushResult."""
    return push_env(SUITE, "alice/reach-suite", episodes=EPISODES, progress=False)


# --- 1. the form ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("tasks", "says"),
    [
        ('"reach-left"', "must be a list of task names"),
        ('["reach-left"]', "a suite has at least two"),
        ('["reach-left", "reach-left"]', "more than once"),
        ('["reach-left", "reach-center,reach-right"]', "without commas"),
        ('["reach-left", 3]', "must be a list of task names"),
    ],
)
def test_a_malformed_tasks_declaration_is_an_error_naming_the_file_and_field(tmp_path, tasks, says):
    folder = copy_env(
        tmp_path, SUITE, edits={"pyproject.toml": lambda s: s.replace(s[s.index("tasks = ") :], f"tasks = {tasks}\n")}
    )
    with pytest.raises(errors.EnvFolderError, match=says) as e:
        EnvFolder.read(folder)
    assert str(folder / "pyproject.toml") in str(e.value) and "[tool.hub-envs] tasks" in str(e.value)


@pytest.mark.parametrize(
    ("tasks", "says"),
    [
        ('["reach-left", "reach-right"]', "does not list the config's default task 'reach-center'"),
        ('["reach-left", "reach-center", "reach-up"]', "the env refuses task 'reach-up'"),
    ],
)
def test_a_task_the_env_does_not_have_is_refused_at_push_before_anything_is_published(hub, tmp_path, tasks, says):
    folder = copy_env(
        tmp_path, SUITE, edits={"pyproject.toml": lambda s: s.replace(s[s.index("tasks = ") :], f"tasks = {tasks}\n")}
    )
    with pytest.raises(errors.EnvFolderError, match=says) as e:
        push_env(folder, "alice/bad-suite", episodes=1, progress=False)
    assert "[tool.hub-envs] tasks" in str(e.value)
    assert not hub.api.repo_exists("alice/bad-suite")


# --- 2. one push, one commit, one dataset of every task ------------------------------------------------------------


def test_a_suite_is_one_commit_with_one_dataset_of_every_task(hub_module, suite):
    commits = hub_module.api.list_repo_commits("alice/reach-suite")  # the push's, on the repo's empty initial commit
    assert suite.created_commit and [c.commit_id for c in commits][0] == suite.sha and len(commits) == 2

    m = suite.manifest
    assert m.format_version == 4 and m.task_names == TASKS
    for i, (task, record) in enumerate(zip(TASKS, m.tasks, strict=True)):
        assert record["task_index"] == i and record["instruction"] == INSTRUCTIONS[task]
        assert record["episodes"] == list(range(i * EPISODES, (i + 1) * EPISODES))
        assert record["seeds"] == record["episodes"]  # episode i resets with seed 0 + i
        assert record["fingerprint"]["seeds"] == record["seeds"] and len(record["fingerprint"]["digest"]) == 64
    assert len({r["fingerprint"]["digest"] for r in m.tasks}) == 3  # each task's own rollouts
    assert m.fingerprint == m.task_record("reach-center")["fingerprint"]  # load_env checks the default task's
    assert [(b["name"], b["task"], b["seeds"]) for b in m.benchmarks] == [
        ("random-policy", r["task"], r["seeds"]) for r in m.tasks
    ]
    assert m.dataset["episodes"] == 3 * EPISODES

    loaded = load_env(f"alice/reach-suite@{suite.sha}", trust_remote_code=True)
    root = loaded.dataset_root
    tasks = pd.read_parquet(root / "meta" / "tasks.parquet")
    assert dict(zip(tasks.index, tasks["task_index"], strict=True)) == {INSTRUCTIONS[t]: i for i, t in enumerate(TASKS)}
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["total_tasks"] == 3 and info["total_episodes"] == 3 * EPISODES
    frames = pd.read_parquet(root / "data" / "chunk-000" / "file-000.parquet")
    for i, task in enumerate(TASKS):  # every frame of a task's episodes carries its task_index, and its target
        rows = frames[frames["episode_index"].isin(m.tasks[i]["episodes"])]
        assert set(rows["task_index"]) == {i}
        assert np.allclose(np.stack(rows["observation.environment_state"]), TARGETS[task])
    dataset = loaded.open_dataset()  # LeRobot's own reader: each frame's task text
    first, last = dataset[0], dataset[len(dataset) - 1]
    assert (first["task"], last["task"]) == (INSTRUCTIONS["reach-left"], INSTRUCTIONS["reach-right"])
    loaded.unregister()

    card = (loaded.path / "README.md").read_text()
    assert "## Tasks" in card
    for i, task in enumerate(TASKS):
        assert f"| {i} | `{task}` | {INSTRUCTIONS[task]} |" in card
    page = urllib.request.urlopen(f"{hub_module.endpoint}/alice/reach-suite").read().decode()  # the Hub's web page
    table = page[page.index("<table", page.index(">Tasks</h2>")) :]
    assert all(f"<code>{t}</code>" in table and INSTRUCTIONS[t] in table for t in TASKS)


def test_pushing_an_unchanged_suite_again_builds_nothing_and_commits_nothing(hub_module, suite):
    again = push_env(SUITE, "alice/reach-suite", episodes=EPISODES, progress=False)
    assert not again.created_commit and again.sha == suite.sha and again.manifest.task_names == TASKS
    assert "build" not in again.timings  # main's manifest said it holds this suite: nothing was regenerated
    assert len(hub_module.api.list_repo_commits("alice/reach-suite")) == 2  # the initial one and the first push's


def test_a_one_task_env_is_published_as_before(hub_module):
    result = push_env(TINY, "alice/tiny-not-a-suite", episodes=1, progress=False)
    manifest = json.loads(Path(hub_module.api.hf_hub_download("alice/tiny-not-a-suite", "hub_env.json")).read_text())
    assert manifest["format_version"] == 3 and "tasks" not in manifest
    assert [b["name"] for b in manifest["benchmarks"]] == ["random-policy"] and "task" not in manifest["benchmarks"][0]
    with load_env(f"alice/tiny-not-a-suite@{result.sha}", trust_remote_code=True) as loaded:
        assert loaded.tasks == [] and not loaded.is_suite
        suite = loaded.make_suite(n_envs=1)
        assert list(suite) == ["tiny-env"] and list(suite["tiny-env"]) == [0]
        suite["tiny-env"][0].close()


# --- 3. load_env: one task, or all ---------------------------------------------------------------------------------


def test_load_env_makes_one_task_or_the_whole_suite(hub_module, suite, capsys):
    with load_env(f"alice/reach-suite@{suite.sha}", trust_remote_code=True) as loaded:
        assert loaded.is_suite and loaded.tasks == TASKS
        assert loaded.config.task == "reach-center"  # the default task
        for task in TASKS:
            env = loaded.for_task(task).make()
            obs, _ = env.reset(seed=0)
            assert obs["environment_state"][0] == pytest.approx(TARGETS[task])
            assert env.unwrapped.task_description == INSTRUCTIONS[task]
            env.close()
        envs = loaded.make_suite(n_envs=2)
        assert list(envs) == ["reach-suite"] and sorted(envs["reach-suite"]) == [0, 1, 2]
        for task_id, vec in envs["reach-suite"].items():
            obs, _ = vec.reset(seed=0)
            assert obs["environment_state"].shape == (2, 1)
            assert np.allclose(obs["environment_state"], TARGETS[TASKS[task_id]])
            vec.close()
        only = loaded.make_suite(tasks=["reach-right"])
        assert list(only["reach-suite"]) == [2]
        only["reach-suite"][2].close()
        with pytest.raises(errors.ConfigError, match="'reach-up' is not one of its tasks; it has"):
            loaded.for_task("reach-up")
    assert cli_main(["load", "--repo_id=alice/reach-suite", f"--revision={suite.sha}", "--trust_remote_code=true"]) == 0
    assert "tasks:       reach-left, reach-center, reach-right (default reach-center)" in capsys.readouterr().out


# --- LeRobot: its own loader, --env.type=hub, lerobot-eval ------------------------------------------------------


def _per_task_targets(envs) -> dict[int, tuple[float, str]]:
    out = {}
    for task_id, vec in envs["reach-suite"].items():
        obs, _ = vec.reset(seed=0)
        out[task_id] = (float(obs["environment_state"][0][0]), vec.call("task_description")[0])
        vec.close()
    return out


def test_lerobots_own_make_env_gets_the_suite_form_from_env_py(hub_module, suite):
    from lerobot.envs.factory import make_env  # heavy: lerobot

    envs = make_env(f"alice/reach-suite@{suite.sha}", n_envs=2, trust_remote_code=True)
    assert _per_task_targets(envs) == {i: (TARGETS[t], INSTRUCTIONS[t]) for i, t in enumerate(TASKS)}


def test_env_type_hub_gives_every_task_or_those_env_task_names(hub_module, suite):
    from hub_envs.lerobot.env import make_env

    def parsed(*extra):
        args = ["--env.type=hub", "--env.repo_id=alice/reach-suite", f"--env.revision={suite.sha}"]
        args += ["--env.trust_remote_code=true", "--policy.type=act", *extra]
        return draccus.parse(EvalPipelineConfig, args=args)

    cfg = parsed()
    assert cfg.env.task == ",".join(TASKS)
    assert _per_task_targets(make_env(cfg.env, n_envs=1)) == {i: (TARGETS[t], INSTRUCTIONS[t]) for i, t in enumerate(TASKS)}
    some = parsed("--env.task=reach-right,reach-left")
    assert _per_task_targets(make_env(some.env, n_envs=1)) == {
        2: (TARGETS["reach-right"], INSTRUCTIONS["reach-right"]),
        0: (TARGETS["reach-left"], INSTRUCTIONS["reach-left"]),
    }
    with pytest.raises(Exception) as e:  # draccus says it could not build the config, from hub-envs' ConfigError
        parsed("--env.task=reach-up")
    assert isinstance(e.value.__cause__, errors.ConfigError)
    assert "--env.task='reach-up' names ['reach-up'], not tasks of this suite; its tasks are" in str(e.value.__cause__)


@pytest.fixture(scope="module")
def one_step_act(hub_module, suite, tmp_path_factory) -> Path:
    """``hub-envs train`` of a tiny ACT for one step on the suite's dataset (every task): its ``pretrained_model``."""
    from hub_envs import _compat

    out = tmp_path_factory.mktemp("train") / "run"
    args = ["train", "--env.type=hub", "--env.repo_id=alice/reach-suite", f"--env.revision={suite.sha}"]
    args += ["--env.trust_remote_code=true", *TINY_ACT, "--batch_size=4", "--num_workers=0"]
    args += [f"--{_compat.train_eval_freq_flag()}=0", "--steps=1", "--save_freq=1", f"--output_dir={out}"]
    assert cli_main(args) == 0
    return out / "checkpoints" / "last" / "pretrained_model"


def test_lerobot_eval_reports_every_task_and_the_suite(hub_module, suite, one_step_act, tmp_path):
    """LeRobot's unmodified ``lerobot-eval`` console script, in a fresh process, on ``--env.type=hub``: one entry per task
    (``per_task``: task group = the suite, task id = the task's index), the suite's aggregate and the overall one."""
    cmd = [
        str(Path(sys.executable).with_name("lerobot-eval")),
        "--env.discover_packages_path=hub_envs.lerobot_plugin",
        "--env.type=hub",
        "--env.repo_id=alice/reach-suite",
        f"--env.revision={suite.sha}",
        "--env.trust_remote_code=true",
        f"--policy.path={one_step_act}",
        "--policy.device=cpu",
        "--eval.n_episodes=2",
        "--eval.batch_size=2",
        f"--output_dir={tmp_path / 'eval'}",
    ]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-4000:]
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert sorted((t["task_group"], t["task_id"]) for t in info["per_task"]) == [("reach-suite", i) for i in range(3)]
    assert all(len(t["metrics"]["sum_rewards"]) == 2 for t in info["per_task"])
    assert info["per_group"]["reach-suite"]["n_episodes"] == 6 and info["overall"]["n_episodes"] == 6


# --- 4. reproduce: per task and for the suite ----------------------------------------------------------------------


def test_reproduce_says_reproduced_per_task_and_for_the_suite(hub_module, suite, tmp_path, capsys):
    code = cli_main(
        [
            "reproduce",
            "--repo_id=alice/reach-suite",
            f"--revision={suite.sha}",
            "--trust_remote_code=true",
            "--workers=1",
            f"--out={tmp_path / 'out'}",
        ]
    )
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert f"REPRODUCED: alice/reach-suite@{suite.sha} (a suite of 3 tasks: 3 of 3 reproduced)" in printed
    for i, task in enumerate(TASKS):
        assert f"task {i} '{task}': REPRODUCED" in printed
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["verdict"] == "REPRODUCED" and report["suite"] == {"tasks": 3, "reproduced": 3}
    for i, (task, part) in enumerate(zip(TASKS, report["tasks"], strict=True)):
        assert (part["task"], part["task_index"], part["verdict"]) == (task, i, "REPRODUCED")
        assert [e["episode"] for e in part["replay"]["episodes"]] == suite.manifest.tasks[i]["episodes"]
        assert [b["name"] for b in part["benchmarks"]] == ["random-policy"] and part["benchmarks"][0]["passed"]
        assert part["fingerprint"]["status"].startswith("matches")
    assert "## Tasks" in (tmp_path / "out" / "report.md").read_text()


def test_a_task_whose_dynamics_changed_is_the_one_not_reproduced(hub_module, suite, tmp_path):
    from helpers import republish

    from hub_envs import reproduce

    def move_the_right_target(folder: Path) -> None:
        code = folder / "reach_suite.py"
        code.write_text(code.read_text().replace('"reach-right": 0.5}', '"reach-right": 0.55}'))

    push_env(SUITE, "alice/reach-suite-edited", episodes=EPISODES, progress=False)
    sha = republish(hub_module.api, "alice/reach-suite-edited", move_the_right_target)
    report = reproduce("alice/reach-suite-edited", revision=sha, trust_remote_code=True, workers=1, write=False, progress=False)
    assert not report.reproduced
    assert [(t.task, t.reproduced) for t in report.tasks] == [
        ("reach-left", True),
        ("reach-center", True),
        ("reach-right", False),
    ]
    right = report.tasks[2]
    assert not right.replay.ok and right.fingerprint["status"] == "drifted"
    assert {d.feature for e in right.replay.diverged for d in e.divergences} >= {"observation.environment_state"}
    assert "task 2 'reach-right': NOT REPRODUCED" in report.summary()


def test_evaluate_reports_each_task_and_the_suite_pooled(hub_module, suite, capsys):
    from hub_envs import evaluate

    whole = evaluate(f"alice/reach-suite@{suite.sha}", episodes=3, trust_remote_code=True, workers=1, progress=False)
    assert [r.task for r in whole.per_task] == TASKS and whole.task is None
    assert all(r.seeds == (0, 1, 2) for r in whole.per_task)  # every task over the same seeds, as lerobot-eval runs them
    assert whole.returns == tuple(x for r in whole.per_task for x in r.returns)
    one = evaluate(
        f"alice/reach-suite@{suite.sha}", episodes=3, trust_remote_code=True, workers=1, progress=False, task="reach-right"
    )
    assert one.task == "reach-right" and one.returns == whole.per_task[2].returns and not one.per_task
    assert one.returns != whole.per_task[0].returns  # another task: another env
    code = cli_main(
        ["evaluate", "--repo_id=alice/reach-suite", f"--revision={suite.sha}", "--trust_remote_code=true", "--episodes=3"]
    )
    printed = capsys.readouterr().out
    assert code == 0 and "(3 tasks): 9 episodes of policy random" in printed
    for task, r in zip(TASKS, whole.per_task, strict=True):
        assert f"task {task!r}: mean return {r.metrics['mean_return']:.6g}" in printed
    with pytest.raises(errors.ConfigError, match="is not one of its tasks"):
        evaluate(f"alice/reach-suite@{suite.sha}", episodes=1, trust_remote_code=True, progress=False, task="reach-up")


def test_compare_pairs_policies_per_task_and_pooled_over_the_suite(hub_module, suite, one_step_act, tmp_path):
    from hub_envs.operations.compare import compare

    report = compare(
        f"alice/reach-suite@{suite.sha}",
        ["random", str(one_step_act)],
        episodes=3,
        trust_remote_code=True,
        trust_policy_code=True,
        workers=1,
        out=tmp_path / "cmp",
        progress=False,
    )
    assert [t.task for t in report.tasks] == TASKS
    for t in report.tasks:
        assert [p.label for p in t.policies] == ["random", str(one_step_act)] and len(t.differences) == 1
        a, b = t.policies
        assert t.differences[0].returns.values == tuple(x - y for x, y in zip(a.returns.values, b.returns.values, strict=True))
    random_per_task = [t.policies[0].returns.values for t in report.tasks]
    assert len({v for v in random_per_task}) == 3  # each task in its own env
    assert report.policies[0].returns.values == tuple(x for v in random_per_task for x in v)  # the suite: pooled
    assert report.differences[0].returns.values == tuple(x for t in report.tasks for x in t.differences[0].returns.values)
    assert "the suite (every task's episodes pooled, 9 per policy):" in report.summary()
    saved = json.loads((tmp_path / "cmp" / "report.json").read_text())
    assert [t["task"] for t in saved["tasks"]] == TASKS
    assert "## Task `reach-left`" in (tmp_path / "cmp" / "report.md").read_text()


# --- red-team round 29 ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name",
    [
        "\x1b]8;;http://evil.example/\x1b\\reach-left\x1b]8;;\x1b\\",  # a terminal hyperlink hiding where it goes
        "\x1b[2J\x1b[Htrust: trust_remote_code=True",  # clears the screen, prints a line of its choosing
        "reach-left\n## Load it",
        "x" * 201,
        "reach-left,reach-right",
    ],
)
def test_a_hand_written_manifest_naming_a_task_push_env_would_refuse_is_refused_at_load(hub_module, suite, name, capsys):
    """A hostile suite writes its hub_env.json itself (upload_folder, not push_env): its task names went to the terminal
    raw through `hub-envs load` (escape sequences included), and into reports, whatever push_env's rule for
    ``[tool.hub-envs] tasks`` (red-team finding, session 29). The manifest is held to that same rule."""
    from hub_envs.errors import ManifestError
    from hub_envs.repo.format import Manifest

    data = json.loads(Path(hub_module.api.hf_hub_download("alice/reach-suite", "hub_env.json", revision=suite.sha)).read_text())
    Manifest.from_json(json.dumps(data), where="the suite")  # as published: read
    data["tasks"][1]["task"] = name
    with pytest.raises(ManifestError, match="a task name is one line") as refused:
        Manifest.from_json(json.dumps(data), where="the suite")
    assert "\x1b" not in str(refused.value) and "\n" not in str(refused.value)


@pytest.mark.parametrize("name", ["pick `red` cube", "``stack``", "a | b", "`x|y`", "plain"])
def test_a_task_name_renders_as_itself_in_a_markdown_table_cell_and_heading(name):
    """Task names are the publisher's text: backticks and pipes in one must not break report.md's task table (the row
    keeps its cells, the name shows as written) nor compare's headings."""
    from markdown_it import MarkdownIt

    from hub_envs._text import md_code

    md = MarkdownIt("commonmark").enable("table")
    tokens = md.parse(f"| id | task | verdict |\n|---|---|---|\n| 0 | {md_code(name)} | ok |\n")
    cells = [t for t in tokens if t.type == "td_open"]
    codes = [c.content for t in tokens if t.type == "inline" for c in t.children or [] if c.type == "code_inline"]
    assert len(cells) == 3 and codes == [name]
    heading = [
        c.content for t in md.parse(f"## Task {md_code(name, table_cell=False)}") if t.type == "inline" for c in t.children
    ]
    assert name in heading
