"""ape_jax: keyframe-focused imitation learning (Wen et al., ICML 2021) in JAX.

The library (APE, weighting functions, models, learners, evaluation) lives
here; environments are in the sibling package `envs`, entry points in
`experiments`.
"""

__version__ = "0.1.0"
