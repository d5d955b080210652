"""The ``hub-envs`` command line meets the habits of LeRobot's and the Hub's users (issue 34 item 5, issue 33 item 2):

* ``hub-envs --version`` (``-V``) names hub-envs and the stack, as ``lerobot-info`` does, importing none of it;
* a mistyped command or flag of any command is a ``UsageError`` (exit code 2, as argparse) that names the command,
  the flag and what was probably meant, answered before torch, lerobot, ray or matplotlib is imported;
* every flag of every command has a help text; the usage line names the command;
* a command that takes a repo id takes it first, without its flag (``hub-envs load user/name@<sha>``).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata as md
import json
import platform
import re
import subprocess
import sys

import pytest
from helpers import TINY

from hub_envs import errors, push_env
from hub_envs._version import __version__
from hub_envs.cli import COMMANDS, push_env_main
from hub_envs.cli import main as cli_main

#: what a command line must not import before it is known to be right (issue 33: ``reproduce --revison`` took 10 s)
HEAVY = ("torch", "lerobot", "ray", "matplotlib")
#: the commands whose flags are LeRobot's own (``lerobot-train``/``lerobot-eval``'s config): a mistyped one of each
LEROBOT_TYPOS = {"train": ("stpes", "steps"), "eval": ("output_dri", "output_dir")}


#: the commands that take a repo id (each with --repo_id, or first without the flag)
REPO_COMMANDS = ("push", "load", "trust", "untrust", "reproduce", "evaluate", "attestations", "compare", "audit")


def _config_fields(name: str) -> list[str]:
    """The flags of a command (its ``Config``'s fields), none when it parses its arguments itself."""
    config = getattr(importlib.import_module(f"hub_envs.cli.{COMMANDS[name].module}"), "Config", None)
    return [f.name for f in dataclasses.fields(config)] if config is not None else []


def _typo(flag: str) -> str:
    """``flag`` with two letters in its middle swapped (``revision`` -> ``revsiion``), as a hurried hand types it."""
    i = len(flag) // 2
    typo = flag[: i - 1] + flag[i] + flag[i - 1] + flag[i + 1 :]
    return typo if typo != flag else flag[:-1]


def _run_python(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)


# --- --version ---------------------------------------------------------------------------------


@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_version_names_hub_envs_and_its_stack_without_importing_it(flag):
    code = (
        "import sys\nfrom hub_envs.cli import main\nrc = main(sys.argv[1:])\n"
        f"print('HEAVY', sorted({{m.split('.')[0] for m in sys.modules}} & {set(HEAVY) | {'gymnasium', 'numpy'}!r}))\n"
        "sys.exit(rc)\n"
    )
    out = _run_python(code, flag)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.splitlines()
    assert lines[0] == f"hub-envs {__version__}", out.stdout
    assert f"- python: {platform.python_version()}" in out.stdout and f"- platform: {platform.platform()}" in lines
    for name in ("lerobot", "huggingface_hub", "gymnasium", "draccus", "numpy", "torch"):
        assert f"- {name}: {md.version(name)}" in lines, out.stdout  # installed on both legs
    assert "- ray: " in out.stdout and "- ffmpeg: " in out.stdout
    assert "HEAVY []" in out.stdout, out.stdout


# --- did you mean ------------------------------------------------------------------------------


@pytest.mark.parametrize(("typed", "meant"), [("reprodcue", "reproduce"), ("evalute", "evaluate"), ("--verison", "--version")])
def test_a_mistyped_command_names_the_closest_one(typed, meant, capsys):
    assert cli_main([typed, "--repo_id=user/name"]) == 2
    err = capsys.readouterr().err
    assert "UsageError" in err and f"{typed!r}" in err and f"did you mean {meant!r}?" in err, err


def test_a_command_nothing_resembles_is_a_usage_error_without_a_guess(capsys):
    assert cli_main(["zzzz"]) == 2
    err = capsys.readouterr().err
    assert "UsageError" in err and "'zzzz'" in err and "did you mean" not in err and "hub-envs --help" in err, err


def test_a_mistyped_flag_of_every_command_is_named_with_its_fix_before_any_heavy_import():
    """One fresh interpreter runs every command of the table with a mistyped flag (the brief's own
    ``reproduce --revison=x`` first) and looks at ``sys.modules`` after each."""
    cases = [("reproduce", "revison", "revision")]
    for name in COMMANDS:
        if name in LEROBOT_TYPOS:
            cases.append((name, *LEROBOT_TYPOS[name]))
        else:
            flag = max(_config_fields(name) or ["repo_id"], key=len)
            cases.append((name, _typo(flag), flag))
    code = (
        "import contextlib, io, json, sys\nfrom hub_envs.cli import main\nout = []\n"
        f"for name, typo, flag in {cases!r}:\n"
        "    err = io.StringIO()\n"
        "    with contextlib.redirect_stderr(err):\n"
        "        try:\n"
        "            rc = main([name, f'--{typo}=x'])\n"
        "        except SystemExit as e:\n"
        "            rc = e.code\n"
        f"    heavy = sorted({{m.split('.')[0] for m in sys.modules}} & {set(HEAVY)!r})\n"
        "    out.append({'name': name, 'typo': typo, 'flag': flag, 'rc': rc, 'err': err.getvalue(), 'heavy': heavy})\n"
        "print(json.dumps(out))\n"
    )
    proc = _run_python(code)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(proc.stdout.splitlines()[-1])
    assert [r["name"] for r in results[1:]] == list(COMMANDS)
    heavy = {r["name"]: r["heavy"] for r in results if r["heavy"]}
    assert not heavy, f"a mistyped flag imported {heavy} before it was named"
    for r in results:
        said = f"{r['name']} --{r['typo']}: {r['err'][-600:]}"
        assert r["rc"] == 2 and "UsageError" in r["err"], said
        assert f"hub-envs {r['name']} has no flag --{r['typo']}" in r["err"], said
        assert f"did you mean --{r['flag']}?" in r["err"], said


def test_a_flag_error_of_push_env_names_push_env(capsys):
    assert push_env_main(["--episods=3"]) == 2
    err = capsys.readouterr().err
    assert "push_env has no flag --episods: did you mean --episodes?" in err, err


def test_a_usage_error_is_a_config_error():
    """Callers that catch ``ConfigError`` (a bad value) catch a bad command line too."""
    assert issubclass(errors.UsageError, errors.ConfigError) and issubclass(errors.UsageError, errors.HubEnvsError)


# --- help on every flag; the usage line names the command ------------------------------------------------


def _help(name: str, capsys) -> str:
    with pytest.raises(SystemExit) as e:
        cli_main([name, "--help"])
    assert e.value.code in (0, None)
    return capsys.readouterr().out


@pytest.mark.parametrize("name", [n for n in COMMANDS if n not in LEROBOT_TYPOS])
def test_every_flag_of_every_command_has_a_help_text(name, capsys):
    """Walks the command table (``train``/``eval`` pass LeRobot's own flags, and help, through)."""
    module = importlib.import_module(f"hub_envs.cli.{COMMANDS[name].module}")
    assert hasattr(module, "Config"), f"hub-envs {name} has no Config: its flags (and their help) cannot be listed"
    text = _help(name, capsys)
    bare = []
    for flag in _config_fields(name):
        entry = re.search(rf"^  --{flag}(?: \S+)?(?P<help>.*?)(?=\n  -|\n\n|\Z)", text, re.M | re.S)
        assert entry is not None, f"hub-envs {name} --help does not show --{flag}:\n{text}"
        words = re.sub(r"\(default:.*?\)\s*$", "", entry["help"].strip(), flags=re.S).strip()
        if not words:
            bare.append(f"--{flag}")
    assert not bare, f"hub-envs {name}: flags without a help text: {bare}"


@pytest.mark.parametrize("name", [n for n in COMMANDS if n not in LEROBOT_TYPOS])
def test_the_usage_line_names_the_command(name, capsys):
    text = _help(name, capsys)
    assert text.startswith(f"usage: hub-envs {name} ") or (name == "push" and f"\n\nusage: hub-envs {name} " in text), text


def test_a_value_draccus_cannot_read_shows_the_commands_usage_line(capsys):
    with pytest.raises(SystemExit) as e:
        cli_main(["reproduce", "--repo_id=user/name", "--workers"])  # a flag without its value
    assert e.value.code == 2
    assert capsys.readouterr().err.startswith("usage: hub-envs reproduce ")


# --- a positional repo id --------------------------------------------------------------------------


def _positional_cases() -> list[tuple[str, list[str], list[str]]]:
    """``(command, with positional values, with flags)`` for every command that takes a repo id."""
    ref = "user/name@" + "a" * 40
    cases = []
    for name in REPO_COMMANDS:
        rest = ["--env_dir=./env"] if name == "push" else []
        cases.append((name, [ref, *rest], [f"--repo_id={ref}", *rest]))
    cases.append(("diff", ["user/name@a", "user/name@b"], ["--old=user/name@a", "--new=user/name@b"]))
    cases.append(("adopt", [ref, "me/name"], [f"--from_repo={ref}", "--repo_id=me/name"]))  # the source, then the new repo
    return cases


@pytest.mark.parametrize(("name", "positional", "flags"), _positional_cases(), ids=lambda v: v if isinstance(v, str) else "")
def test_a_positional_repo_id_is_its_flag(name, positional, flags):
    from hub_envs.cli import parse_command

    assert parse_command(name, positional) == parse_command(name, flags)
    assert parse_command(name, [*positional, *flags]) == parse_command(name, flags)  # both, the same: fine


def test_every_command_with_a_repo_id_flag_is_tested_with_it_positional():
    own_positionals = {"adopt"}  # its POSITIONAL: the source repo, then the repo to publish (a case of its own above)
    assert sorted(n for n in COMMANDS if "repo_id" in _config_fields(n) and n not in own_positionals) == sorted(REPO_COMMANDS)


def test_a_repo_id_given_twice_differently_names_both(capsys):
    sha = "a" * 40
    assert cli_main(["reproduce", f"alice/reach@{sha}", "--repo_id=alice/other"]) == 2
    err = capsys.readouterr().err
    assert "UsageError" in err and f"'alice/reach@{sha}'" in err and "--repo_id=alice/other" in err, err
    assert cli_main(["load", "alice/reach", "alice/other"]) == 2
    err = capsys.readouterr().err
    assert "UsageError" in err and "'alice/other'" in err and "hub-envs load" in err, err


@pytest.fixture(scope="module")
def published(hub_module) -> str:
    return push_env(TINY, "user/name", episodes=1, progress=False).sha


def test_load_trust_and_attestations_take_the_repo_id_first(published, capsys, tmp_path, monkeypatch):
    """What the issue's acceptance runs: ``hub-envs load user/name@<sha> --trust_remote_code=true``."""
    monkeypatch.chdir(tmp_path)
    assert cli_main(["load", f"user/name@{published}", "--trust_remote_code=true", "--json=true"]) == 0
    loaded = json.loads(capsys.readouterr().out)
    assert (loaded["repo_id"], loaded["revision"]) == ("user/name", published)
    assert cli_main(["trust", f"--repo_id=user/name@{published}"]) == 0  # and trust takes the flag too
    assert f"Trusted user/name@{published}" in capsys.readouterr().out
    assert cli_main(["untrust", "user/name"]) == 0 and "Removed 1 trust entry" in capsys.readouterr().out
    assert cli_main(["attestations", "user/name"]) == 0
    assert "Reproduction attestations of user/name" in capsys.readouterr().out


# --- the _compat reach that lets train/eval answer before LeRobot is imported -------------------------


@pytest.mark.parametrize(
    ("command", "module", "cls"), [("train", "train", "TrainPipelineConfig"), ("eval", "eval", "EvalPipelineConfig")]
)
def test_lerobots_pipeline_flags_are_read_without_importing_it(command, module, cls):
    """The flags read from LeRobot's source are exactly its config's init fields (fails when LeRobot moves them)."""
    from hub_envs._compat import lerobot_pipeline_flags

    config = getattr(importlib.import_module(f"lerobot.configs.{module}"), cls)
    assert lerobot_pipeline_flags(command) == {f.name for f in dataclasses.fields(config) if f.init}


# --- red-team round 29 ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", ["yaml", "json"])
def test_a_config_file_never_gives_consent_to_run_a_repos_code(hub, tmp_path, monkeypatch, capsys, suffix):
    """Every command takes draccus' --config_path: a config file someone shared holding ``trust_remote_code: true`` made
    `hub-envs load`, `audit` and `adopt` run the repo's code without consent on the command line (red-team finding,
    session 29; docs/security.md: a config never carries consent)."""
    import warnings

    import plain_repos as pr

    marker = tmp_path / "RAN"
    monkeypatch.setenv("HUB_ENVS_TEST_MARKER", str(marker))
    payload = f"\nimport os, pathlib\npathlib.Path(os.environ['HUB_ENVS_TEST_MARKER']).write_text('ran')  # {suffix}\n"
    hub.api.create_repo("bob/shared")
    folder = pr.write(tmp_path / "shared", {"env.py": pr.REACH + pr.VECTOR_MAKE_ENV + payload, "requirements.txt": "numpy\n"})
    sha = hub.api.upload_folder(repo_id="bob/shared", folder_path=str(folder)).oid
    config = tmp_path / f"shared.{suffix}"
    config.write_text(
        f"repo_id: bob/shared@{sha}\ntrust_remote_code: true\n"
        if suffix == "yaml"
        else json.dumps({"repo_id": f"bob/shared@{sha}", "trust_remote_code": True})
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for argv in (
            ["load", f"--config_path={config}"],
            ["audit", f"--config_path={config}"],
            ["adopt", f"--config_path={config}", f"--from_repo=bob/shared@{sha}", "--repo_id=me/shared"],
        ):
            assert cli_main(argv) == 1
            err = capsys.readouterr().err
            assert "ConfigError" in err and "sets trust_remote_code" in err and "never carries consent" in err, err
            assert not marker.exists()
        # consent on the command line, the rest from the file: as before
        assert cli_main(["load", f"--config_path={config}", "--trust_remote_code=true"]) == 0
    assert marker.exists()


def test_an_unknown_flag_is_named_without_its_escape_sequences(capsys):
    """The "did you mean" message printed an unknown flag raw: escape sequences in a command line a script builds from
    other text reached the terminal (red-team finding, session 29)."""
    assert cli_main(["load", "--re\x1b[2Jvision=main", "u/e"]) == 2
    err = capsys.readouterr().err
    assert "\x1b" not in err and "--re\\x1b[2Jvision" in err, err
