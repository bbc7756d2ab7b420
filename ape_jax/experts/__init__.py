"""Training the experts: soft actor-critic from `brax.training`'s parts, resumable (`sac`); the action statistics
that tell a rough expert from a smooth one (`stats`, which reads ψ from `ape_jax.ape`).

`python -m experiments.train_expert --env NAME` drives it and exports the best policy into
`envs/experts/NAME/`; the shipped experts, their files and loading them (no training code)
are `envs.experts`'. Apart from the jit-pure core and the sweep's pipeline: neither imports
it, and it imports neither.
"""
