"""Attestations of a benchmark suite, per task: ``hub-envs reproduce --attest=true`` on a suite records each task's
verdict (attestation format 2; a one-task env's stays 1), ``hub-envs attestations`` lists "N/M tasks" and each task,
the card's "Reproduced on" table says how many tasks and has a per-task table, and the embedded Hub's repo page shows
the suite's task table from its manifest and the reproductions matrix per task. Against the loopback Hub, through the
unmodified huggingface_hub client.
"""

from __future__ import annotations

import contextlib
import copy
import html as html_lib
import io
import json
import re
import urllib.request
from pathlib import Path

import pytest
from helpers import FIXTURES, TINY, republish
from huggingface_hub import CommitOperationAdd, hf_hub_download
from test_pages import browser  # noqa: F401 - the browser fixture (Debian's chromium through Playwright), reused

from hub_envs import errors, push_env, reproduce
from hub_envs.cli import main as cli_main
from hub_envs.repo.attestations import Attestation, AttestationEntry, matrix_text

SUITE = FIXTURES / "suite_env"
REPO = "alice/att-suite"
TASKS = ["reach-left", "reach-center", "reach-right"]
INSTRUCTIONS = {
    "reach-left": "move the point to the left target",
    "reach-center": "move the point to the middle",
    "reach-right": "move the point to the right target",
}


@pytest.fixture(scope="module")
def pushed(hub_module):
    return push_env(SUITE, REPO, episodes=2, progress=False)


@pytest.fixture(scope="module")
def attested(hub_module, pushed, tmp_path_factory):
    """``hub-envs reproduce --attest=true`` on the suite: (the PR's attestation path, its bytes)."""
    out = tmp_path_factory.mktemp("suite-report")
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = cli_main(
            ["reproduce", REPO, f"--revision={pushed.sha}", "--trust_remote_code=true", "--workers=1", f"--out={out}",
             "--attest=true"]
        )  # fmt: skip
    assert code == 0
    assert "Attested REPRODUCED (3 of 3 tasks) for alice/att-suite@" in printed.getvalue()
    api = hub_module.api
    (path,) = [f for f in api.list_repo_files(REPO, revision="refs/pr/1") if f.startswith("reproductions/")]
    local = hf_hub_download(REPO, path, revision="refs/pr/1", endpoint=hub_module.endpoint, force_download=True)
    return path, Path(local).read_bytes()


def test_a_suite_attestation_records_each_tasks_verdict_in_format_2(pushed, attested):
    _path, data = attested
    att = Attestation.from_json(data)
    raw = json.loads(data)
    assert raw["format_version"] == 2 and att.format_version == 2
    assert [t["task"] for t in att.tasks] == TASKS and [t["task_index"] for t in att.tasks] == [0, 1, 2]
    assert att.verdict == "REPRODUCED" and att.tasks_reproduced == (3, 3)
    for t, record in zip(att.tasks, pushed.manifest.tasks, strict=True):
        assert t["verdict"] == "REPRODUCED" and t["checks"] and all(t["checks"].values())
        assert t["replay"]["ok"] and t["replay"]["episodes"] == len(record["episodes"]) == 2
        (bench,) = t["benchmarks"]
        assert bench["passed"] and bench["seeds"] == next(
            b["seeds"] for b in pushed.manifest.benchmarks if b["task"] == t["task"]
        )
        assert t["fingerprint"]["ok"]
    assert "(3 of 3 tasks)" in att.summary()


def test_attestations_lists_n_of_m_tasks_and_each_task_then_the_card_shows_them_per_task(hub_module, pushed, attested, capsys):
    path, _data = attested
    assert cli_main(["attestations", REPO]) == 0
    listing = capsys.readouterr().out
    assert "✓ 3/3 tasks unsigned (PR #1)" in listing
    assert "3 of 3 tasks reproduced: reach-left ✓, reach-center ✓, reach-right ✓" in listing
    hub_module.api.merge_pull_request(REPO, 1)
    again = push_env(SUITE, REPO, episodes=2, progress=False)  # the card gains its "Reproduced on" table
    assert again.created_commit
    card = Path(hf_hub_download(REPO, "README.md", revision=again.sha, endpoint=hub_module.endpoint)).read_text()
    section = card[card.index("## Reproduced on") :]
    (row,) = [line for line in section.splitlines() if f"`{pushed.sha[:12]}`" in line and "reproduced" in line]
    assert "✓ reproduced, 3 of 3 tasks |" in row
    assert "Per task" in section
    for task in TASKS:
        assert f"| `{task}` | ✓ |" in section
    # the page of the repo (the embedded Hub's): the matrix cell says 3/3 tasks and each task's mark
    page = urllib.request.urlopen(f"{hub_module.endpoint}/{REPO}").read().decode()
    matrix = page[page.index('id="reproductions"') : page.index("</section>", page.index('id="reproductions"'))]
    text = " ".join(html_lib.unescape(re.sub(r"<[^>]+>", " ", matrix)).split())
    assert "✓ 3/3 tasks" in text
    assert all(f"{t} ✓" in text for t in TASKS)


def test_the_repo_page_shows_the_suites_task_table_from_its_manifest(hub_module, pushed):
    page = urllib.request.urlopen(f"{hub_module.endpoint}/{REPO}/tree/{pushed.sha}").read().decode()
    assert 'id="suite-tasks"' in page
    table = page[page.index('id="suite-tasks"') : page.index("</section>", page.index('id="suite-tasks"'))]
    text = " ".join(html_lib.unescape(re.sub(r"<[^>]+>", " ", table)).split())
    assert "3 tasks" in text
    for i, task in enumerate(TASKS):
        record = pushed.manifest.tasks[i]
        assert f"{i} {task} {INSTRUCTIONS[task]} {len(record['episodes'])} {record['fingerprint']['digest'][:12]}" in text
        bench = next(b for b in pushed.manifest.benchmarks if b["task"] == task)
        assert f"{bench['metrics']['success_rate']:.4g}" in text


def test_a_one_task_repo_page_has_no_task_table(hub_module):
    sha = push_env(TINY, "alice/att-one", episodes=2, progress=False).sha
    page = urllib.request.urlopen(f"{hub_module.endpoint}/alice/att-one/tree/{sha}").read().decode()
    assert 'id="suite-tasks"' not in page


HOSTILE_TASK = "<script>alert('task')</script>"
HOSTILE_INSTRUCTION = '<img src=x onerror="alert(1)">'


@pytest.fixture(scope="module")
def hostile(hub_module, pushed):
    """The suite republished by hand with a manifest whose task name, instruction and digest are markup, and an open
    pull request adding a suite attestation whose task names are markup: the revision's sha."""

    def edit(folder: Path) -> None:
        m = json.loads((folder / "hub_env.json").read_text())
        m["tasks"][0]["task"] = HOSTILE_TASK
        m["tasks"][1]["instruction"] = HOSTILE_INSTRUCTION
        m["tasks"][2]["fingerprint"] = {"digest": "</table><b>x</b>"}
        (folder / "hub_env.json").write_text(json.dumps(m))

    sha = republish(hub_module.api, REPO, edit)
    record = {
        "kind": "hub-envs reproduction attestation",
        "sha": sha,
        "verdict": "NOT REPRODUCED",
        "stack_digest": "0123456789ab",
        "stack": {"python": "3.13.1"},
        "tasks": [{"task": HOSTILE_INSTRUCTION, "reproduced": True}, {"task": HOSTILE_TASK, "reproduced": False}],
    }
    hub_module.api.create_commit(
        REPO,
        [CommitOperationAdd("reproductions/2026-01-02-hostile.json", json.dumps(record).encode())],
        commit_message="a hostile record",
        create_pr=True,
    )
    return sha


def _section(page: str, marker: str) -> str:
    return page[page.index(marker) : page.index("</section>", page.index(marker))]


def test_task_names_and_instructions_a_hand_made_repo_holds_are_escaped_on_the_page(hub_module, hostile):
    page = urllib.request.urlopen(f"{hub_module.endpoint}/{REPO}/tree/{hostile}").read().decode()
    for part in (_section(page, 'id="suite-tasks"'), _section(page, 'id="reproductions"')):
        assert "<script>alert" not in part and "<img src=x" not in part and "<b>x</b>" not in part
    assert "&lt;script&gt;alert(&#39;task&#39;)&lt;/script&gt;" in _section(page, 'id="suite-tasks"')
    matrix = " ".join(html_lib.unescape(re.sub(r"<[^>]+>", " ", _section(page, 'id="reproductions"'))).split())
    assert "✗ 1/2 tasks" in matrix and f"{HOSTILE_TASK} ✗" in matrix


def test_in_a_browser_the_hostile_task_table_and_matrix_run_nothing(hub_module, hostile, browser):  # noqa: F811
    context = browser.new_context()
    try:
        page = context.new_page()
        dialogs: list[str] = []
        page.on("dialog", lambda d: (dialogs.append(d.message), d.dismiss()))
        page.goto(f"{hub_module.endpoint}/{REPO}/tree/{hostile}")
        page.wait_for_load_state("load")
        rows = page.locator("#suite-tasks tbody tr")
        assert rows.count() == 3
        assert rows.nth(0).locator("td").nth(1).inner_text() == HOSTILE_TASK  # shown as text
        assert rows.nth(1).locator("td").nth(2).inner_text() == HOSTILE_INSTRUCTION
        marks = page.locator(".repro-matrix .task-marks li").all_inner_texts()
        assert f"{HOSTILE_TASK} ✗" in marks and f"{HOSTILE_INSTRUCTION} ✓" in marks
        assert page.locator("#suite-tasks img, #suite-tasks script, .repro-matrix img, .repro-matrix script").count() == 0
        assert dialogs == []
    finally:
        context.close()


# --- the format, without a Hub --------------------------------------------------------------------------------------


def _suite_dict(attested) -> dict:
    return json.loads(attested[1])


def test_tasks_need_format_2_and_must_agree_with_the_verdict(attested):
    d = _suite_dict(attested)
    with pytest.raises(errors.AttestationError, match="'tasks' needs format_version 2"):
        Attestation.from_dict({**d, "format_version": 1})
    one_fails = copy.deepcopy(d)
    one_fails["tasks"][2]["reproduced"] = False  # a task's verdict that contradicts it
    with pytest.raises(errors.AttestationError, match=r"tasks\[2\]"):
        Attestation.from_dict(one_fails)
    one_fails["tasks"][2]["verdict"] = "NOT REPRODUCED"
    one_fails["tasks"][2]["checks"] = {k: False for k in one_fails["tasks"][2]["checks"]}
    with pytest.raises(errors.AttestationError, match="'reproduced' contradicts 'tasks'"):
        Attestation.from_dict(one_fails)  # the suite says REPRODUCED while a task did not
    twice = copy.deepcopy(d)
    twice["tasks"][1]["task"] = twice["tasks"][0]["task"]
    with pytest.raises(errors.AttestationError, match="distinct tasks"):
        Attestation.from_dict(twice)


def test_a_suite_with_a_task_not_reproduced_says_which(attested):
    d = copy.deepcopy(_suite_dict(attested))
    t = d["tasks"][2]
    t.update(reproduced=False, verdict="NOT REPRODUCED", checks={k: False for k in t["checks"]})
    d["checks"] = {k: (False if k.startswith("task reach-right:") else v) for k, v in d["checks"].items()}
    d.update(reproduced=False, verdict="NOT REPRODUCED")
    att = Attestation.from_dict(d)
    entry = AttestationEntry("reproductions/x.json", "merged", att.sha, att, None, b"{}", None)
    text = matrix_text([entry])
    assert "✗ 2/3 tasks unsigned" in text and "2 of 3 tasks reproduced: reach-left ✓, reach-center ✓, reach-right ✗" in text


def test_a_one_task_attestation_stays_format_1_without_tasks(hub_module, tmp_path):
    sha = push_env(TINY, "alice/att-one-task", episodes=2, progress=False).sha
    report = reproduce(f"alice/att-one-task@{sha}", trust_remote_code=True, workers=1, out=tmp_path, progress=False)
    att = Attestation.from_report(report, command=["hub-envs", "reproduce"])
    assert att.format_version == 1 and "tasks" not in json.loads(att.to_json()) and att.tasks == ()
    assert att.tasks_reproduced == (0, 0) and "tasks" not in att.summary()


def test_server_and_repo_format_agree_on_the_suite_field():
    import dataclasses

    from hub_envs.repo.format import Manifest
    from hub_envs.server.formats import MANIFEST_TASKS

    assert MANIFEST_TASKS in {f.name for f in dataclasses.fields(Manifest)}
