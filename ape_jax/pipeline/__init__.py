"""The host pipeline: everything that touches files, caches and checkpoints.

The sweep as typed phases (`sweep`), its settings records (`presets`, `spec`), demonstrations (`collect`,
`data`, `minari_io`), checkpoints and saved policies (`checkpoint`), the results file (`results`), curves
(`logs`) and provenance. The jit-pure core in `ape_jax` never imports this package; the layers are
described in `docs/design.md`.
"""
