"""`experiments.bench_train --share`: a grid's rate in one process and as pinned single-threaded processes side by
side (their shares of the models summed), and the flags refused together."""

import os
import subprocess
import sys

import pytest

from experiments import _share


def test_pinned_workers_train_their_shares_of_the_grid_and_their_rates_add_up():
    one = _share.grid_rate("mlp", 3, 10, 1)
    assert one["updates_s"] > 0 and one["gflops"] > 0 and one["compile_s"] >= 0
    cores = min(2, len(os.sched_getaffinity(0)))
    pinned = _share.pinned_rates("mlp", 3, 10, 1, cores)
    assert pinned["updates_s"] > 0 and pinned["gflops"] > 0
    # FLOP/s per update are the recipe's: the two measures count the same work per model-update
    assert pinned["gflops"] / pinned["updates_s"] == pytest.approx(one["gflops"] / one["updates_s"], rel=1e-9)


def test_methods_only_and_share_are_refused_together_in_one_line():
    proc = subprocess.run([sys.executable, "-m", "experiments.bench_train", "--methods-only", "--share"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "give one" in proc.stderr and len(proc.stderr.strip().splitlines()) <= 2


def test_the_profiles_chain_is_the_recipes_network_and_each_stage_trains():
    cfg = _share.recipe_config("bn-mlp", 10)
    assert _share.layer_widths(cfg) == [10, 300, 300, 300, 100, 300, 3]   # FCA's network on Hopper `pos`, H 2
    assert _share.layer_widths(_share.recipe_config("mlp", 10))[0] == 10
    rates = {stage: _share.stage_rate("bn-mlp", 2, 3, 1, stage) for stage in _share.PROFILE_STAGES}
    assert all(r > 0 for r in rates.values())
