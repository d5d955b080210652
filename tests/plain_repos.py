"""Plain LeRobot EnvHub repos (no hub_env.json), as people publish them with ``HfApi().upload_folder``: the forms
LeRobot's ``make_env`` accepts, and one that breaks its contract. Written into a folder, then uploaded by the tests."""

from __future__ import annotations

from pathlib import Path

#: A small reach task in LeRobot's conventions: ``agent_pos``, ``info["is_success"]``, a time limit, seeded resets.
REACH = """
import gymnasium as gym
import numpy as np


class Reach(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode="rgb_array", target=0.5):
        self.render_mode = render_mode
        self.target = np.full(2, target, dtype=np.float32)
        self.observation_space = gym.spaces.Dict({"agent_pos": gym.spaces.Box(-2.0, 2.0, (2,), np.float32)})
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.task = "reach the target"

    def _obs(self):
        return {"agent_pos": self.pos.copy()}

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = self.np_random.uniform(-1.0, 1.0, 2).astype(np.float32)
        return self._obs(), {"is_success": False}

    def step(self, action):
        self.pos = np.clip(self.pos + 0.2 * np.clip(action, -1, 1), -2, 2).astype(np.float32)
        dist = float(np.linalg.norm(self.pos - self.target))
        success = dist < 0.15
        return self._obs(), -dist, success, False, {"is_success": success}

    def render(self):
        frame = np.zeros((32, 32, 3), dtype=np.uint8)
        x, y = ((self.pos + 2) / 4 * 31).astype(int)
        frame[y, x] = 255
        return frame
"""

VECTOR_MAKE_ENV = """

def make_env(n_envs=1, use_async_envs=False, cfg=None):
    fns = [lambda: gym.wrappers.TimeLimit(Reach(), max_episode_steps=40) for _ in range(n_envs)]
    vec = gym.vector.AsyncVectorEnv if use_async_envs else gym.vector.SyncVectorEnv
    return vec(fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
"""

BARE_MAKE_ENV = """

def make_env(n_envs=1, use_async_envs=False, cfg=None):
    return gym.wrappers.TimeLimit(Reach(), max_episode_steps=40)
"""

REQUIREMENTS = "gymnasium>=1.0\nnumpy  # arrays\n"


def write(folder: Path, files: dict[str, str]) -> Path:
    """``files`` (path -> text) written under ``folder``."""
    for rel, text in files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(text)
    return folder


def vector_repo(folder: Path) -> Path:
    """``env.py`` whose make_env returns one vector env (SAME_STEP autoreset, as lerobot-eval needs)."""
    return write(folder, {"env.py": REACH + VECTOR_MAKE_ENV, "requirements.txt": REQUIREMENTS, "README.md": "# reach\n"})


def bare_repo(folder: Path) -> Path:
    """``env.py`` whose make_env returns a bare ``gym.Env``."""
    return write(folder, {"env.py": REACH + BARE_MAKE_ENV, "requirements.txt": REQUIREMENTS})


def folder_repo(folder: Path) -> Path:
    """Entry files under a folder, one per task (``user/name:envs/Near.py``), no ``env.py``."""
    near = REACH + VECTOR_MAKE_ENV.replace("Reach()", "Reach(target=0.2)")
    far = REACH + VECTOR_MAKE_ENV.replace("Reach()", "Reach(target=1.5)")
    return write(folder, {"envs/Near.py": near, "envs/Far.py": far, "requirements.txt": REQUIREMENTS})


#: A benchmark suite in LeRobot's form: ``make_env`` returns ``{suite: {task_id: VectorEnv}}``, each env stating its
#: task's name as ``task`` and its instruction as ``task_description`` (where LeRobot's LIBERO and Meta-World envs do).
SUITE_MAKE_ENV = """

TASKS = {
    "reach-near": (0.2, "reach the near target"),
    "reach-far": (1.5, "reach the far target"),
    "reach-origin": (0.0, "go back to the origin"),
}


class ReachTask(Reach):
    def __init__(self, name, render_mode="rgb_array"):
        target, description = TASKS[name]
        super().__init__(render_mode=render_mode, target=target)
        self.task = name
        self.task_description = description


def make_env(n_envs=1, use_async_envs=False, cfg=None):
    vec = gym.vector.AsyncVectorEnv if use_async_envs else gym.vector.SyncVectorEnv
    one = lambda name: gym.wrappers.TimeLimit(ReachTask(name), max_episode_steps=40)  # noqa: E731
    return {
        "reach_suite": {
            i: vec([lambda name=name: one(name) for _ in range(n_envs)], autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
            for i, name in enumerate(TASKS)
        }
    }
"""
SUITE_TASKS = ["reach-near", "reach-far", "reach-origin"]
SUITE_INSTRUCTIONS = ["reach the near target", "reach the far target", "go back to the origin"]


def suite_repo(folder: Path) -> Path:
    """``env.py`` whose make_env returns a suite of three tasks (LeRobot's ``{suite: {task_id: VectorEnv}}``)."""
    return write(folder, {"env.py": REACH + SUITE_MAKE_ENV, "requirements.txt": REQUIREMENTS, "README.md": "# reach suite\n"})


def two_suites_repo(folder: Path) -> Path:
    """``env.py`` whose make_env returns two suites of one task each, whose envs all state the same ``task``;
    ``empty.py`` breaks the contract with a suite of no task."""
    make = """

def make_env(n_envs=1, use_async_envs=False, cfg=None):
    def vec(target):
        fns = [lambda: gym.wrappers.TimeLimit(Reach(target=target), max_episode_steps=40) for _ in range(n_envs)]
        return gym.vector.SyncVectorEnv(fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)

    return {"near": {0: vec(0.2)}, "far": {0: vec(1.5)}}
"""
    empty = "\n\ndef make_env(n_envs=1, use_async_envs=False, cfg=None):\n    return {'near': {}}\n"
    return write(folder, {"env.py": REACH + make, "empty.py": REACH + empty, "requirements.txt": REQUIREMENTS})


#: The installed package a shim repo names in its requirements.txt (built as a wheel by the tests).
PACKAGE = "hub-envs-fixture-reach"
PACKAGE_FILES = {"hub_envs_fixture_reach/__init__.py": REACH + VECTOR_MAKE_ENV}


def shim_repo(folder: Path) -> Path:
    """A thin ``env.py`` over an installed package its ``requirements.txt`` names."""
    return write(
        folder,
        {"env.py": "from hub_envs_fixture_reach import make_env  # noqa: F401\n", "requirements.txt": f"{PACKAGE}==1.0.0\n"},
    )


def broken_repo(folder: Path) -> Path:
    """Breaks the contract: ``env.py`` has no make_env; ``returns_list.py``'s make_env returns a list."""
    return write(
        folder,
        {
            "env.py": REACH,
            "returns_list.py": REACH + "\n\ndef make_env(n_envs=1, use_async_envs=False, cfg=None):\n    return [Reach()]\n",
        },
    )
