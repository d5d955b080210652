"""The harness: run an env's episodes and judge what comes out (the episode engine, the checks, replay, benchmarks,
reports, provenance). It imports the dataset wing and the repo format below it, never loading, the backends or the
operations above it, which pass it envs and folders."""
