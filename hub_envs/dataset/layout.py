"""The LeRobot v3.0 dataset layout: paths, path templates and the keys every dataset carries.

One place for what LeRobot's own ``lerobot/datasets/utils.py`` defines (its values as of lerobot 0.4.4,
unchanged through 0.6.x; ``tests/test_dataset.py`` compares them with the installed lerobot's) and for the
keys hub-envs adds: ``next.reward``/``next.done``/``next.success`` per frame and the recorded simulator
states beside the data.

    >>> sorted(BOOKKEEPING_KEYS)[:3], DATA_PATH.format(chunk_index=0, file_index=2)
    (['episode_index', 'frame_index', 'index'], 'data/chunk-000/file-002.parquet')
"""

from __future__ import annotations

# --- LeRobot v3.0 layout constants (lerobot/datasets/utils.py, lerobot 0.4.4) -------------------

CODEBASE_VERSION = "v3.0"
DEFAULT_CHUNK_SIZE = 1000  # max files per chunk folder
DEFAULT_DATA_FILE_SIZE_IN_MB = 100
DEFAULT_VIDEO_FILE_SIZE_IN_MB = 200
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_DIR = "meta/episodes"
DATA_DIR = "data"
VIDEO_DIR = "videos"
CHUNK_FILE_PATTERN = "chunk-{chunk_index:03d}/file-{file_index:03d}"
EPISODES_PATH = EPISODES_DIR + "/" + CHUNK_FILE_PATTERN + ".parquet"
DATA_PATH = DATA_DIR + "/" + CHUNK_FILE_PATTERN + ".parquet"
VIDEO_PATH = VIDEO_DIR + "/{video_key}/" + CHUNK_FILE_PATTERN + ".mp4"
DEFAULT_FEATURES: dict[str, dict] = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
NEXT_FEATURES: dict[str, dict] = {
    "next.reward": {"dtype": "float32", "shape": [1], "names": None},
    "next.done": {"dtype": "bool", "shape": [1], "names": None},
    "next.success": {"dtype": "bool", "shape": [1], "names": None},
}

#: The per-step outcome keys hub-envs records beside the observations and the action.
NEXT_KEYS = tuple(NEXT_FEATURES)
#: Keys every LeRobot dataset has, or hub-envs adds, that no env feature maps to.
BOOKKEEPING_KEYS = frozenset(DEFAULT_FEATURES) | frozenset(NEXT_FEATURES)
#: The name under which recorded simulator states are compared (not a dataset column; see ``states``).
STATE_FEATURE = "env_state"
#: Simulator states recorded beside the data (``hub_envs.dataset.states``).
STATES_PATH = "meta/env_states.parquet"
#: hub-envs' own metadata (reset seeds, how the stats differ from LeRobot's, ``env_meta``): a file of its own in
#: ``meta/``, which LeRobot never reads, so LeRobot >= 0.5 does not log "Unknown fields in DatasetInfo" as it does
#: for the ``info.json["hub_envs"]`` key datasets written before kept it in (still read: :func:`~hub_envs.dataset.reader.read_hub_envs_meta`).
HUB_ENVS_META_PATH = "meta/hub_envs.json"
#: Where datasets written before :data:`HUB_ENVS_META_PATH` existed keep the same metadata: a key of ``meta/info.json``.
LEGACY_INFO_KEY = "hub_envs"
#: The episodes-metadata column, one per video feature, holding ``hub_envs.dataset.video.frames_sha256`` of the
#: episode's frames as the env rendered them (before the lossy encoder): replay checks the frames it renders
#: against it. LeRobot's reader ignores it, as it ignores the ``seed`` column.
FRAMES_SHA256_COLUMN = "frames_sha256/{key}"
