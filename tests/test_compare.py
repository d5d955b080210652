"""``hub-envs compare``: policies on the same seeds of one env commit, each with CIs, and the seed-paired difference.

The trained policy is a real (tiny) ACT from ``hub-envs train`` (LeRobot's lerobot-train), one step on reach's
bundled dataset: trained or not, it acts differently from the random policy, which is all the paired CI needs.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers import copy_env, saved_figures
from test_lerobot import EVAL_FREQ, TINY_ACT

from hub_envs import compare, errors, push_env
from hub_envs.cli import main as cli_main
from hub_envs.operations.compare import CompareReport, Estimate, PolicyResult, _paired, episodes_for_half_width

ENVS = Path(__file__).resolve().parent.parent / "envs"


@pytest.fixture(scope="module")
def reach(hub_module, tmp_path_factory):
    folder = copy_env(
        tmp_path_factory.mktemp("reach"),
        ENVS / "reach",
        "reach",
        edits={"config.py": lambda s: s.replace("episode_length: int = 100", "episode_length: int = 12")},
    )
    return push_env(folder, "alice/reach-compare", episodes=1, progress=False)


@pytest.fixture(scope="module")
def act_checkpoint(reach, tmp_path_factory) -> Path:
    """A one-step ACT trained by ``hub-envs train`` on reach's bundled dataset: a real pretrained_model folder."""
    out = tmp_path_factory.mktemp("act") / "train"
    args = [
        "train",
        "--env.type=hub",
        "--env.repo_id=alice/reach-compare",
        f"--env.revision={reach.sha}",
        "--env.trust_remote_code=true",
        *TINY_ACT,
        "--batch_size=4",
        "--num_workers=0",
        "--log_freq=100",
        f"--{EVAL_FREQ}=0",
        "--steps=1",
        "--save_freq=1",
        f"--output_dir={out}",
    ]
    assert cli_main(args) == 0
    model = out / "checkpoints" / "last" / "pretrained_model"
    assert (model / "config.json").is_file()
    return model


def test_random_against_itself_differs_by_exactly_zero_on_paired_seeds(hub_module, reach, tmp_path, capsys):
    code = cli_main(
        ["compare", f"--repo_id=alice/reach-compare@{reach.sha}", "--policies=random,random", "--episodes=4",
         "--seed=3", "--trust_remote_code=true", "--workers=1", f"--out={tmp_path}"]
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    data = json.loads((tmp_path / "report.json").read_text())
    assert data["sha"] == reach.sha and data["seeds"] == [3, 4, 5, 6]
    a, b = data["policies"]
    assert (a["label"], b["label"]) == ("random", "random (2)")
    assert a["returns"] == b["returns"] and a["successes"] == b["successes"]
    (d,) = data["differences"]
    assert d["returns"] == {"values": [0.0] * 4, "mean": 0.0, "ci": [0.0, 0.0]}
    assert d["successes"] == {"values": [0.0] * 4, "mean": 0.0, "ci": [0.0, 0.0]}
    assert "random - random (2) (paired over seeds): success +0.0 points" in printed
    assert (tmp_path / "report.md").read_text().startswith("# Policy comparison on `alice/reach-compare`")
    assert (tmp_path / "report.png").stat().st_size > 0
    assert {"load", "policy random", "policy random (2)"} <= set(data["timings"])
    assert (
        data["provenance"]["versions_here"]["pybullet"] and data["provenance"]["content_digest"] == reach.manifest.content_digest
    )


def test_a_trained_act_against_random_on_reach_reports_a_paired_ci(hub_module, reach, act_checkpoint, tmp_path):
    report = compare(
        f"alice/reach-compare@{reach.sha}",
        [str(act_checkpoint), "random"],
        episodes=4,
        trust_remote_code=True,
        workers=1,
        out=tmp_path,
        progress=False,
    )
    act, rnd = report.policies
    assert act.spec == {"type": "lerobot", "path": str(act_checkpoint.resolve())} and rnd.spec == {"type": "random"}
    assert len(act.returns.values) == len(rnd.returns.values) == 4 and act.returns.values != rnd.returns.values
    (d,) = report.differences
    assert d.returns.values == tuple(x - y for x, y in zip(act.returns.values, rnd.returns.values))
    assert d.returns.ci[0] <= d.returns.mean <= d.returns.ci[1] and d.returns.ci[0] < d.returns.ci[1]
    assert act.returns.ci[0] <= act.returns.mean <= act.returns.ci[1]
    assert d.episodes_for_5_points is None or d.episodes_for_5_points >= 1
    md = (tmp_path / "report.md").read_text()
    assert "## Paired differences" in md and f"| {act_checkpoint} - random |" in md


def test_compare_refuses_bad_input_with_a_clear_error(hub_module, reach, tmp_path):
    with pytest.raises(errors.ConfigError, match="at least two"):
        compare(f"alice/reach-compare@{reach.sha}", ["random"], trust_remote_code=True)
    with pytest.raises(errors.ConfigError, match="neither 'random'"):
        compare(f"alice/reach-compare@{reach.sha}", ["random", "./no/such/folder"], trust_remote_code=True)
    with pytest.raises(errors.ReproductionError, match="config.json"):
        compare(f"alice/reach-compare@{reach.sha}", ["random", str(tmp_path)], trust_remote_code=True, write=False)


def test_against_runs_one_policy_on_two_commits_and_pairs_it_with_itself(hub_module, reach):
    """--against (two revisions of one env, the same policy, the same seeds): here a commit against itself, so each
    seed's paired difference is exactly 0; the revision journey (tests/journeys) compares two that differ."""
    ref = f"alice/reach-compare@{reach.sha}"
    report = compare(ref, ["random"], against=ref, episodes=3, trust_remote_code=True, workers=1, write=False, progress=False)
    arm = f"random on @{reach.sha[:12]}"
    assert [p.label for p in report.policies] == [arm, f"{arm} (2)"]
    (paired,) = report.differences
    assert paired.returns.values == (0.0, 0.0, 0.0) and paired.successes.values == (0.0, 0.0, 0.0)
    assert report.provenance["against"]["sha"] == reach.sha and report.envs == f"{ref} and {ref}"
    assert report.policies[0].returns.values == report.policies[1].returns.values != (0.0, 0.0, 0.0)


def test_an_isolated_env_compares_to_the_same_numbers(hub_module, reach, act_checkpoint):
    """--isolation=process: the env steps in worker processes, the policies run here; the comparison is the same."""
    kw = dict(episodes=2, trust_remote_code=True, workers=1, write=False, progress=False)
    here = compare(f"alice/reach-compare@{reach.sha}", [str(act_checkpoint), "random"], **kw)
    isolated = compare(f"alice/reach-compare@{reach.sha}", [str(act_checkpoint), "random"], isolation="process", **kw)
    assert (isolated.settings["isolation"], here.settings["isolation"]) == ("process", "none")

    def numbers(report):  # all but the wall-clock seconds
        return [(p.label, p.spec, p.returns, p.successes, p.episodes_for_5_points) for p in report.policies]

    assert numbers(isolated) == numbers(here)
    assert isolated.differences == here.differences and here.differences[0].returns.values != (0.0, 0.0)
    with pytest.raises(errors.ConfigError, match="isolaton="):
        compare(f"alice/reach-compare@{reach.sha}", ["random", "random"], isolaton="process", **kw)


# --- the plot -------------------------------------------------------------------------------------


def _report(names: list[str], successes: list[list[float]]) -> CompareReport:
    """A report of ``names`` with these per-seed successes (returns follow them), as compare() builds it."""
    stats = dict(resamples=200, confidence=0.95, seed=0)
    results = [
        PolicyResult(
            label=name,
            spec={"type": "lerobot", "path": name},
            returns=Estimate.of([10.0 * s - i for i, s in enumerate(succ)], **stats),
            successes=Estimate.of(succ, **stats),
            episodes_for_5_points=episodes_for_half_width(succ),
            seconds=1.0,
        )
        for i, (name, succ) in enumerate(zip(names, successes))
    ]
    diffs = [_paired(results[0], results[1], **stats)]
    provenance = {"repo_id": "alice/reach", "sha": "0" * 40, "seeds": list(range(len(successes[0])))}
    return CompareReport(
        policies=results, differences=diffs, provenance=provenance, settings={"confidence": 0.95, "resamples": 200}
    )


def plotted(report: CompareReport, tmp_path: Path, monkeypatch):
    """The matplotlib figure report.png is saved from (the one report.write() builds)."""
    import hub_envs.operations.compare as policy_compare

    figures = saved_figures(monkeypatch, policy_compare)
    report.write(tmp_path)
    (fig,) = figures
    assert (tmp_path / "report.png").stat().st_size > 0
    return fig


@pytest.mark.parametrize("rates", [(0.0, 0.0), (1.0, 1.0), (0.25, 0.75)])
def test_the_plot_tells_two_checkpoints_apart_and_draws_success_rates_on_0_to_100(rates, tmp_path, monkeypatch):
    """Two checkpoints named alike get labels that differ, each mapped to its full name in a legend; the success-rate
    axis is 0-100 % whatever the rates (both 0 drew an axis of negative percentages)."""
    names = ["a/last/pretrained_model", "b/last/pretrained_model"]
    seeds = 4
    successes = [[1.0] * round(seeds * r) + [0.0] * (seeds - round(seeds * r)) for r in rates]
    fig = plotted(_report(names, successes), tmp_path, monkeypatch)
    success_ax, return_ax, diff_ax = fig.axes
    for ax in (success_ax, return_ax):
        ticks = [t.get_text() for t in ax.get_xticklabels()]
        assert len(ticks) == 2 and ticks[0] != ticks[1], ticks
    assert success_ax.get_title() == "success rate (%)"
    assert success_ax.get_ylim() == (0.0, 100.0)
    assert [b.get_height() for b in success_ax.patches] == pytest.approx([100 * r for r in rates])
    # every shortened label is explained: "short  =  full name", in the figure's legend
    (legend,) = fig.legends
    explained = dict(t.get_text().split("  =  ") for t in legend.get_texts())
    assert {explained.get(t, t) for t in ticks} == set(names), (ticks, explained)
    assert ticks[0] in diff_ax.get_title() and ticks[1] in diff_ax.get_title()


@pytest.mark.parametrize(
    "names",
    [
        ["a/last/pretrained_model", "b/last/pretrained_model"],
        ["random", "outputs/train/act/checkpoints/last/pretrained_model"],
        ["out/act_1/checkpoints/last/pretrained_model", "out/act_2/checkpoints/last/pretrained_model", "random"],
        ["/home/u/outputs/train/run_with_a_really_long_name_1/x", "/home/u/outputs/train/run_with_a_really_long_name_2/x"],
        ["alice/act@0123456789abcdef0123456789abcdef01234567", "alice/act@0123456789abcdef0123456789abcdef01234568"],
        ["random", "random (2)"],
    ],
)
def test_the_plots_policy_labels_are_never_ambiguous(names, tmp_path, monkeypatch):
    """Whatever the names, the bars' labels differ, each is a shortening of its own name, and the legend (when a
    label is not the whole name) gives the full name."""
    fig = plotted(_report(names, [[0.0, 1.0, 0.0]] * len(names)), tmp_path, monkeypatch)
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert len(set(labels)) == len(names), (names, labels)
    explained = dict(t.get_text().split("  =  ") for legend in fig.legends for t in legend.get_texts())
    for label, name in zip(labels, names):
        assert explained.get(label, label) == name, (label, explained)
        assert all(part.strip("/") in name for part in label.split("…") if part.strip("/")), (label, name)
        assert len(label) <= 32 or label == name, label
