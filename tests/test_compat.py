"""What hub-envs takes from upstream packages that moved between the stacks it supports.

Each test holds one reach of :mod:`hub_envs._compat` to what the installed upstream really does, so a
new lerobot, huggingface_hub, draccus or Python release that moves it fails here, by name, instead of
somewhere deep in a load. The suite runs on both ends of the range (``make test``: ``.venv`` and
``.venv-compat``), so each test checks the answer of the stack it runs on.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import subprocess
import sys
import time

import pytest
from packaging.version import Version

from hub_envs import _compat, errors, load_env
from hub_envs.testing import hub_environment


def test_the_stack_is_one_of_the_two_ends_of_the_supported_range():
    lerobot, hf = _compat.LEROBOT_VERSION, _compat.HF_HUB_VERSION
    assert lerobot is not None
    if sys.version_info >= (3, 12):
        assert lerobot >= Version("0.5"), "lerobot >= 0.5 is what Python >= 3.12 should resolve to"
        assert hf.major >= 1
    assert Version("0.4.4") <= lerobot < Version("0.7")
    assert (hf.major >= 1) == (lerobot >= Version("0.5")), "lerobot >= 0.5 requires huggingface_hub >= 1.6"


def test_env_config_choices_is_lerobots_live_registry():
    from lerobot.envs.configs import EnvConfig

    choices = _compat.env_config_choices()
    assert "pusht" in choices and choices["pusht"] is EnvConfig.get_choice_class("pusht")

    @dataclasses.dataclass
    class Probe(EnvConfig):
        @property
        def gym_kwargs(self) -> dict:
            return {}

    EnvConfig.register_subclass("hub_envs_compat_probe")(Probe)
    try:
        assert _compat.env_config_choices()["hub_envs_compat_probe"] is Probe
    finally:
        _compat.env_config_choices().pop("hub_envs_compat_probe")
    with pytest.raises(KeyError):
        EnvConfig.get_choice_class("hub_envs_compat_probe")


def test_processor_step_names_lists_lerobots_registry_and_ours():
    from lerobot.processor.pipeline import ProcessorStepRegistry

    import hub_envs.loading.processors  # noqa: F401  (registers hub-envs' built-in steps)

    names = _compat.processor_step_names()
    assert "hub_envs/clip_action" in names
    assert all(ProcessorStepRegistry.get(n) is not None for n in names)


def test_hf_transform_to_torch_turns_dataset_columns_into_tensors():
    import torch

    out = _compat.hf_transform_to_torch()({"action": [[0.5], [1.0]]})
    assert all(isinstance(x, torch.Tensor) for x in out["action"])


def test_train_dataset_hooks_name_what_lerobot_train_calls():
    from lerobot.scripts import lerobot_train

    hooks = _compat.train_dataset_hooks()
    assert hooks, "lerobot_train builds its dataset with neither make_dataset nor make_train_eval_datasets"
    expected = "make_train_eval_datasets" if _compat.LEROBOT_VERSION >= Version("0.5") else "make_dataset"
    assert expected in hooks and all(callable(getattr(lerobot_train, h)) for h in hooks)


def test_env_configs_create_their_envs_from_lerobot_0_5_on():
    assert _compat.env_configs_create_envs() == (_compat.LEROBOT_VERSION >= Version("0.5"))


def test_reset_http_sessions_gives_the_next_request_a_new_session():
    from huggingface_hub.utils import get_session

    before = get_session()
    _compat.reset_http_sessions()
    assert get_session() is not before


def test_an_unreachable_endpoint_is_a_hub_error_on_this_client(tmp_path):
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with hub_environment(f"http://127.0.0.1:{port}", tmp_path / "hf_home"):
        with pytest.raises(errors.HubError) as e:
            load_env("someone/nothing-here")
    assert "cannot reach the Hub" in str(e.value) and isinstance(e.value.__cause__, _compat.NETWORK_ERRORS)


def _sleep_forever() -> None:
    time.sleep(600)


def test_terminate_new_children_stops_only_children_started_since():
    before = _compat.live_children()
    proc = multiprocessing.get_context("fork").Process(target=_sleep_forever)
    proc.start()
    assert proc.pid in _compat.live_children()
    _compat.terminate_new_children(before)
    proc.join(10)
    assert not proc.is_alive()


@pytest.mark.parametrize("argv", [["--help"], ["trust", "--help"], ["push", "--help"]])
def test_the_cli_answers_help_without_importing_torch_or_lerobot(argv):
    code = (
        "import sys\n"
        "from hub_envs.cli import main\n"
        "try:\n"
        f"    rc = main({argv!r})\n"
        "except SystemExit as e:\n"
        "    rc = e.code or 0\n"
        "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'lerobot'))\n"
        "print('HEAVY', heavy)\n"
        "sys.exit(rc)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "HEAVY []" in out.stdout, out.stdout[-500:]
    assert "usage" in (out.stdout + out.stderr).lower()
