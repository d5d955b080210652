"""What env authors meet when their env depends on real third-party packages (issue 29, item 8).

The third-party packages are real distributions, built as wheels here and installed by pip into a site folder
on ``sys.path`` (as ``pip install`` would put them in site-packages): one that registers gymnasium ids when
imported, as gymnasium-robotics re-registers gymnasium's MuJoCo ids; one installed under another distribution
name than the requirement that provides its import name, as highway-env's ``pygame-ce`` provides ``import pygame``.
"""

from __future__ import annotations

import sys
import warnings

import gymnasium as gym
import pytest
from helpers import build_wheel, copy_env, install_wheels

from hub_envs import errors, load_env, push_env
from hub_envs.envcode.registration import snapshot_registries
from hub_envs.repo.requirements import check_requirements, unmet_requirements

#: gymnasium's own id, which the "robotics" package below registers again with an entry of its own
TAKEN = "CartPole-v1"
ROBOTICS = f'''import gymnasium as gym

gym.register("{TAKEN}", entry_point="hub_envs_fixture_robotics.cartpole:CartPole", max_episode_steps=500)
gym.register("HubEnvsFixtureReach-v0", entry_point="hub_envs_fixture_robotics.cartpole:CartPole")
'''
CARTPOLE = "from gymnasium.envs.classic_control.cartpole import CartPoleEnv\n\n\nclass CartPole(CartPoleEnv):\n    pass\n"


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A site folder holding the fixture distributions, on ``sys.path`` for the test: hub-envs-fixture-robotics
    (registers gym ids when imported) and hub-envs-fixture-game-ce 2.5 (provides ``import hub_envs_fixture_game``)."""
    wheels = tmp_path / "wheels"
    build_wheel(
        wheels,
        "hub-envs-fixture-robotics",
        "1.4.0",
        {"hub_envs_fixture_robotics/__init__.py": ROBOTICS, "hub_envs_fixture_robotics/cartpole.py": CARTPOLE},
        ("gymnasium>=1.0",),
    )
    build_wheel(wheels, "hub-envs-fixture-game-ce", "2.5.0", {"hub_envs_fixture_game/__init__.py": "SPEED = 2.0\n"})
    folder = install_wheels(
        wheels, tmp_path / "site", "--no-deps", "hub-envs-fixture-robotics==1.4.0", "hub-envs-fixture-game-ce==2.5.0"
    )
    original = gym.registry[TAKEN]
    monkeypatch.syspath_prepend(str(folder))
    yield folder
    gym.registry[TAKEN] = original  # what importing the package did, undone for the next tests
    gym.registry.pop("HubEnvsFixtureReach-v0", None)
    for name in [m for m in sys.modules if m.startswith(("hub_envs_fixture_robotics", "hub_envs_fixture_game"))]:
        del sys.modules[name]


def _env_importing(tmp_path, module: str, requirement: str, extra: str = ""):
    return copy_env(
        tmp_path,
        name=f"uses_{module}",
        edits={
            "tiny.py": lambda t: (
                t.replace("import numpy as np\n", f"import numpy as np\nimport {module}  # noqa: F401\n", 1) + extra
            ),
            "pyproject.toml": lambda t: t.replace('"numpy>=1.26"]', f'"numpy>=1.26", "{requirement}"]'),
        },
    )


def test_an_env_importing_a_package_that_re_registers_gym_ids_publishes_and_loads(hub, site, tmp_path):
    """gymnasium-robotics re-registers gymnasium's MuJoCo ids when imported: push_env refused such an env with
    advice to remove gym.register calls its author never wrote. What a package does on import is its own."""
    env = _env_importing(tmp_path, "hub_envs_fixture_robotics", "hub-envs-fixture-robotics>=1.0")
    pushed = push_env(env, "alice/uses-robotics", episodes=1, progress=False)
    assert gym.registry[TAKEN].entry_point == "hub_envs_fixture_robotics.cartpole:CartPole"  # the package's doing
    loaded = load_env(f"alice/uses-robotics@{pushed.sha}", trust_remote_code=True)
    assert loaded.report.fingerprint.startswith("matches")
    loaded.unregister()


def test_ids_the_envs_own_code_takes_over_are_still_refused_naming_the_code(hub, site, tmp_path):
    own = f"\ngym.register({TAKEN!r}, entry_point=TinyEnv)\n"
    env = _env_importing(tmp_path, "hub_envs_fixture_robotics", "hub-envs-fixture-robotics>=1.0", extra=own)
    before = snapshot_registries()
    with pytest.raises(errors.RegistrationConflictError) as info:
        load_env(env, check=False)
    said = str(info.value)
    assert f"its code replaced gym id {TAKEN!r}" in said and "Remove the env code's own gym.register" in said
    # nothing half-registered: the package's re-registrations are rolled back with everything else
    assert snapshot_registries() == before


def test_a_failed_load_after_a_package_re_registered_ids_leaves_the_registries_as_they_were(hub, site, tmp_path):
    env = _env_importing(tmp_path, "hub_envs_fixture_robotics", "hub-envs-fixture-robotics>=1.0")
    project = env / "pyproject.toml"
    project.write_text(project.read_text().replace('config = "tiny:TinyEnvConfig"', 'config = "tiny:NoSuchConfig"'))
    before = snapshot_registries()
    with pytest.raises(errors.InvalidRepoFormatError, match="NoSuchConfig"):
        load_env(env, check=False)
    assert snapshot_registries() == before


def test_a_requirement_another_distribution_provides_the_import_of_is_a_warning_not_a_refusal(hub, site, tmp_path):
    """highway-env installs pygame-ce, which provides ``import pygame``: a requirement ``pygame`` was refused with
    advice to pip install pygame over pygame-ce's files. Here: hub-envs-fixture-game-ce provides the import of
    ``hub-envs-fixture-game``."""
    assert unmet_requirements(["hub-envs-fixture-game>=2.0"]) == []
    with pytest.warns(errors.RequirementStandInWarning) as seen:
        check_requirements(["hub-envs-fixture-game>=2.0"], repo="alice/highway")
    (warning,) = seen
    assert (
        "alice/highway requires hub-envs-fixture-game>=2.0, which is not installed, but `import hub_envs_fixture_game` "
        "comes from hub-envs-fixture-game-ce 2.5.0 (installed)" in str(warning.message)
    )
    # a version outside the requirement is still unmet, without advice to install the second distribution
    with pytest.raises(errors.MissingRequirementsError) as info:
        check_requirements(["hub-envs-fixture-game>=3", "hub-envs-fixture-absent"], repo="alice/highway")
    said = str(info.value)
    assert "`import hub_envs_fixture_game` comes from hub-envs-fixture-game-ce 2.5.0, outside >=3" in said
    assert "pip install hub-envs-fixture-absent\n" in said + "\n" and "pip install hub-envs-fixture-game" not in said
    assert "would write over the files of the distribution that provides its import name" in said

    # and an env that requires it publishes, with the warning
    env = _env_importing(tmp_path, "hub_envs_fixture_game", "hub-envs-fixture-game>=2.0")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pushed = push_env(env, "alice/uses-game", episodes=1, progress=False)
    assert any(issubclass(w.category, errors.RequirementStandInWarning) for w in caught)
    assert pushed.sha
