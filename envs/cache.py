"""Where the project keeps what it makes on this machine (demonstrations, imported experts, compiled programs):
`cache_dir()`. It lives here, on the bottom floor, because the environments' expert store needs it as much as
the pipeline does, and nothing in `envs` may import from above it."""

from __future__ import annotations

import os
import pathlib


def cache_dir() -> pathlib.Path:
    """`$APE_JAX_CACHE`, else `$XDG_CACHE_HOME/ape_jax`, else `~/.cache/ape_jax`."""
    if os.environ.get("APE_JAX_CACHE"):
        return pathlib.Path(os.environ["APE_JAX_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
    return pathlib.Path(base) / "ape_jax"
