"""The paper's method: weights from the action prediction error (APE, `ape_jax.ape`).

- `ours-step` — the ⌊THR·N⌋ samples with the largest APE weigh W, the others
  1, at each (THR, W) of its grid (`StepKnobs`, `--set ours-step.grid=0.1:5`;
  the paper's: THR 10%, 20% × W 3, 5, 10);
- `ours-softmax` — each minibatch weighted by `B · softmax(APE / τ)`, at each τ
  of its temperatures (`SoftmaxKnobs`, `--set ours-softmax.taus=0.2`; the
  paper's: 0.1, 0.2, 0.5, 1, 5, 10).

Both read row 0 of the score table, the APE, and train in the grid program.
"""

from __future__ import annotations

from ape_jax import methods


def _register(name: str, kind: str, label: str) -> None:
    methods.register(methods.Method(name, label, grid=methods.weighting_grid(kind, None, name),
                                    hparams=methods.weighting_hparams(kind), role="ours", module=__name__,
                                    knobs=methods.weighting_knobs(kind, None)))


_register("ours-step", "step", "Ours (step)")
_register("ours-softmax", "softmax", "Ours (softmax)")
