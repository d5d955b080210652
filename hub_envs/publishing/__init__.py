"""``push_env``: an env folder checked, built into a repo (dataset, media, manifest, card) and published."""
