"""Regenerate the pictures of hub-envs' own output that README, docs/publishing.md and docs/reproduce.md show, from
real runs against an embedded Hub:

- docs/hover-rollout.gif: envs/hover's card GIF, as push_env renders it;
- docs/reproduce-video.png: the `hub-envs reproduce` plot of envs/reach published with video (30-step episodes);
- docs/compare-plot.png: the `hub-envs compare` plot of two one-step ACT checkpoints trained on reach's dataset
  (seeds 1 and 2), given by the paths LeRobot writes (`.../checkpoints/last/pretrained_model`).

    PYTHONPATH=. .venv/bin/python scripts/docs-pictures.py docs

The PNGs are quantized to 128 colours. Takes a few minutes (two one-step trainings, 2 x 8 compare episodes).
"""

import os
import shutil
import sys
import tempfile
from pathlib import Path

from PIL import Image

from hub_envs import compare, push_env, reproduce
from hub_envs._compat import train_eval_freq_flag
from hub_envs.cli import main as cli_main
from hub_envs.testing import HubServer, hub_environment

ROOT = Path(__file__).resolve().parent.parent
TINY_ACT = ["--policy.type=act", "--policy.push_to_hub=false", "--policy.device=cpu", "--policy.dim_model=32",
            "--policy.n_heads=2", "--policy.dim_feedforward=64", "--policy.n_encoder_layers=1",
            "--policy.n_decoder_layers=1", "--policy.chunk_size=10", "--policy.n_action_steps=10",
            "--policy.use_vae=false", "--policy.pretrained_backbone_weights=null"]  # fmt: skip


def png(src: Path, dest: Path) -> None:
    Image.open(src).convert("RGB").quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(dest, optimize=True)


def main(out: Path) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="hub-envs-docs-pictures-"))
    try:
        with HubServer(tmp / "hub") as server, hub_environment(server.endpoint, tmp / "hf"):
            hover = push_env(ROOT / "envs" / "hover", "docs/hover", episodes=3, progress=False)
            shutil.copy(server_file("docs/hover", "media/rollout.gif", hover.sha), out / "hover-rollout.gif")

            reach = push_env(ROOT / "envs" / "reach", "docs/reach", episodes=3, progress=False, config={"episode_length": 30})
            report = reproduce(
                f"docs/reach@{reach.sha}", trust_remote_code=True, workers=1, out=tmp / "reproduce", progress=False
            )
            png(Path(report.paths["png"]), out / "reproduce-video.png")

            runs = tmp / "outputs" / "train"
            for name, seed in (("act_a", 1), ("act_b", 2)):
                args = ["train", "--env.type=hub", "--env.repo_id=docs/reach", f"--env.revision={reach.sha}",
                        "--env.trust_remote_code=true", *TINY_ACT, "--batch_size=4", "--num_workers=0", "--log_freq=100",
                        f"--{train_eval_freq_flag()}=0", "--steps=1", "--save_freq=1", f"--seed={seed}",
                        f"--output_dir={runs / name}"]  # fmt: skip
                assert cli_main(args) == 0, name
            policies = [f"outputs/train/{name}/checkpoints/last/pretrained_model" for name in ("act_a", "act_b")]
            here = Path.cwd()
            try:
                os.chdir(tmp)  # the paths as typed after LeRobot's training, relative to where it wrote outputs/
                result = compare(f"docs/reach@{reach.sha}", [f"./{p}" for p in policies], episodes=8,
                                 trust_remote_code=True, workers=1, out=tmp / "compare", progress=False)  # fmt: skip
            finally:
                os.chdir(here)
            png(Path(result.paths["png"]), out / "compare-plot.png")
            print(result.summary())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def server_file(repo_id: str, path: str, sha: str) -> str:
    from huggingface_hub import hf_hub_download

    return hf_hub_download(repo_id, path, revision=sha)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else ROOT / "docs"))
