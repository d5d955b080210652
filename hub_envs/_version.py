"""hub-envs' version (one place: the package face, reports and manifests read it from here)."""

__version__ = "0.1.0"
