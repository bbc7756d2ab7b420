"""ape_jax: keyframe-focused imitation learning (Wen et al., ICML 2021) in JAX.

The library (APE, weighting functions, models, learners, evaluation) lives
here; environments are in the sibling package `envs`, entry points in
`experiments`.
"""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("ape_jax")  # pyproject.toml's, as installed
except _metadata.PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0.0.0+unknown"
