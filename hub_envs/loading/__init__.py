"""``load_env``: a repo id in, a verified, trusted, registered and checked env out (:mod:`hub_envs.loading.load`)."""
