"""Where a result came from (`ape_jax.pipeline.provenance`, whose names the command-line tools import from here too)."""

from ape_jax.pipeline.provenance import ROOT, machine, system

__all__ = ["ROOT", "machine", "system"]
