"""``hub-envs diff`` on benchmark suites, against a real loopback Hub: a suite against itself, a revision that renames a
task, changes an instruction, moves a target and adds a task (the per-task table, the suite's verdict), and a suite
against the same env published as one task.

Real parts only: the loopback Hub server, huggingface_hub, LeRobot's EnvConfig and dataset, gymnasium.
"""

from __future__ import annotations

import json

import pytest
from helpers import FIXTURES, copy_env

from hub_envs import push_env
from hub_envs.cli import main as cli_main

SUITE = FIXTURES / "suite_env"
TASKS = ["reach-left", "reach-center", "reach-right"]


def _push(folder, repo_id):
    return push_env(folder, repo_id, episodes=2, progress=False).sha


def _diff(old, new, out, capsys, *flags):
    code = cli_main(["diff", f"--old={old}", f"--new={new}", "--trust_remote_code=true", f"--out={out}", *flags])
    return code, capsys.readouterr().out, json.loads((out / "report.json").read_text()), (out / "report.md").read_text()


@pytest.fixture(scope="module")
def base(hub_module):
    """alice/suite, the three-task fixture suite published once: its sha."""
    return _push(SUITE, "alice/suite")


def test_a_suite_against_itself_is_identical_task_by_task_with_the_same_seeds_paired(base, tmp_path, capsys):
    code, out, report, md = _diff(f"alice/suite@{base}", f"alice/suite@{base}", tmp_path, capsys)
    assert code == 0, out
    assert "IDENTICAL BEHAVIOUR" in out and "Suite: suite vs suite (3 tasks -> 3 tasks); 0 of 3 task(s) differ" in out
    assert report["suite"]["old"] == report["suite"]["new"] == 3
    assert [(t["old"], t["new"], t["change"], t["identical"]) for t in report["tasks"]] == [(t, t, "kept", True) for t in TASKS]
    for i, t in enumerate(report["tasks"]):
        # each task replays its own dataset episodes (2 per task, seeds 2i, 2i+1), then random-action seeds, paired
        assert [s["seed"] for s in t["seeds"]][:2] == [2 * i, 2 * i + 1] and len(t["seeds"]) == 4
        assert all(s["task"] == t["new"] and not s["diverged"] for s in t["seeds"])
        assert t["fingerprint"]["same"] and t["fingerprint"]["live_old"] == t["fingerprint"]["recorded_old"]
        (bench,) = t["benchmarks"]  # the task's own random-policy benchmark, re-run on both
        assert bench["task"] == t["new"] and bench["episodes_differing"] == [] and bench["metrics"]
        assert t["deltas"]["return"]["mean"] == 0.0
    # pooled: every task's episodes, matched by task and seed
    assert len(report["seeds"]) == 12 and report["deltas"]["return"]["n"] == 12
    assert "| task | change | instruction |" in md
    assert "| reach-right | kept | 'move the point to the right target' | 0 of 4 |" in md


def test_renamed_added_reworded_and_changed_tasks_each_say_so_and_the_suite_differs(base, tmp_path, capsys):
    def edit_code(text):
        text = text.replace('"reach-left": -0.5', '"reach-west": -0.5').replace('"reach-right": 0.5', '"reach-right": 0.6')
        text = text.replace('"reach-left": "move', '"reach-west": "move')
        text = text.replace('"move the point to the middle"', '"bring the point to the centre"')
        return text.replace("TARGETS = {", 'TARGETS = {"reach-far": 0.9, ').replace(
            "INSTRUCTIONS = {", 'INSTRUCTIONS = {"reach-far": "move the point far right", '
        )

    folder = copy_env(
        tmp_path,
        SUITE,
        edits={
            "reach_suite.py": edit_code,
            "pyproject.toml": lambda t: t.replace('"reach-left"', '"reach-west"').replace(
                '"reach-right"]', '"reach-right", "reach-far"]'
            ),
        },
    )
    new = _push(folder, "alice/suite")
    code, out, report, md = _diff(f"alice/suite@{base}", f"alice/suite@{new}", tmp_path / "o", capsys)
    assert code == 1, out
    assert "BEHAVIOUR DIFFERS" in out and "suite vs suite (3 tasks -> 4 tasks); 4 of 4 task(s) differ" in out
    by = {(t["old"], t["new"]): t for t in report["tasks"]}
    assert list(by) == [
        ("reach-center", "reach-center"),
        ("reach-right", "reach-right"),
        ("reach-left", "reach-west"),
        (None, "reach-far"),
    ]
    west = by[("reach-left", "reach-west")]  # the same instruction and target under a new name: a rename
    assert west["change"] == "renamed" and west["behaviour_identical"] and not west["identical"]
    assert west["verdict"] == "identical behaviour (renamed)"
    center = by[("reach-center", "reach-center")]
    assert center["instruction_changed"] and center["behaviour_identical"]
    assert center["instruction_new"] == "bring the point to the centre"
    right = by[("reach-right", "reach-right")]  # its target moved: the same seeds diverge, in this task only
    assert right["verdict"] == "behaviour differs" and right["seeds"][0]["diverged"] and not right["fingerprint"]["same"]
    assert right["seeds"][0]["feature"] in ("observation.environment_state", "next.reward")
    assert by[(None, "reach-far")]["change"] == "added" and by[(None, "reach-far")]["seeds"] == []
    assert "task 'reach-right' seed 4 (recorded actions of episode 4)" in out
    assert "| reach-left -> reach-west | renamed | 'move the point to the left target' | 0 of 4 |" in md
    assert "'move the point to the middle' -> 'bring the point to the centre'" in md
    assert "| reach-far | added |" in md


def test_a_suite_against_a_one_task_env_says_so_plainly(base, tmp_path, capsys):
    single = copy_env(tmp_path, SUITE, edits={"pyproject.toml": lambda t: t[: t.index("tasks = ")]})
    one = _push(single, "alice/suite-one")
    code, out, report, _md = _diff(f"alice/suite@{base}", f"alice/suite-one@{one}", tmp_path / "o", capsys)
    assert code == 1, out
    kind = report["suite"]["kind"]
    assert kind.startswith("the old revision is a suite of 3 tasks, the new one a one-task env")
    assert "'reach-center'" in kind and kind in out
    rows = [(t["old"], t["new"], t["change"]) for t in report["tasks"]]
    assert rows == [("reach-left", None, "removed"), ("reach-center", "", "vs one-task env"), ("reach-right", None, "removed")]
    paired = report["tasks"][1]  # the one-task env is the suite's default task: the same behaviour
    assert paired["behaviour_identical"] and [s["seed"] for s in paired["seeds"]][:2] == [2, 3]
