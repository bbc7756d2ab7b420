"""`experiments.compare_runs`: the runs two sweeps share, their returns and how far their parameters are apart."""

import numpy as np
import pytest

from ape_jax.pipeline import results
from ape_jax.pipeline.checkpoint import save_policies
from experiments import compare_runs


def _sweep(folder, runs, weights):
    """A finished sweep's --out folder: results.json with `runs` (identity, return) and their parameters."""
    folder.mkdir()
    losses = {"unweighted": 0.0, "changepoint": 0.0, "copycat": 0.0}
    records = [{"method": m, "hparams": hp, "seed": s, "status": "ok", "eval": {"return_mean": ret},
                "losses": {"train": losses, "val": losses}} for m, hp, s, ret in runs]
    # the smallest file `results.load` accepts: compare_runs reads it through the one reader
    results.save(folder / "results.json", results.Results(
        env="hopper", obs="pos", preset="quick", config={"iterations": 1, "seeds": 1, "eval_episodes": 1},
        expert={"return_mean": None, "return_std": None, "random_return_mean": None}, runs=records, summary=[],
        settings={"protocol": {}, "budget": {}, "recipe": {}}, system={}))
    save_policies(folder / "params", {"h2": {"runs": [{"method": m, "hparams": hp, "seed": s} for m, hp, s, _ in runs],
                                             "params": {"w": np.asarray(weights, np.float32)},
                                             "obs_mean": np.zeros(3, np.float32), "obs_std": np.ones(3, np.float32)}})
    return folder


def test_shared_runs_are_matched_by_identity_and_their_differences_summed_up(tmp_path, capsys):
    a = _sweep(tmp_path / "a", [("bc-oh", {}, 0, 100.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 0, 200.0)],
               [[1.0, 2.0], [3.0, 4.0]])
    # b holds the same two runs in the other order, one more seed, and the ours run's weights moved by 0.5
    b = _sweep(tmp_path / "b", [("ours-step", {"w": 5.0, "thr": 0.1}, 0, 230.0), ("bc-oh", {}, 1, 50.0),
                                ("bc-oh", {}, 0, 110.0)], [[3.5, 4.0], [0.0, 0.0], [1.0, 2.0]])
    rows = compare_runs.compare(a, b)
    assert [(r["method"], r["seed"], r["return_a"], r["return_b"]) for r in rows] == [
        ("bc-oh", 0, 100.0, 110.0), ("ours-step", 0, 200.0, 230.0)]
    assert [r["param_max_abs_diff"] for r in rows] == [0.0, pytest.approx(0.5)]
    assert compare_runs.main([str(a), str(b)]) == 0
    assert ("2 shared runs: |return A − return B| median 20.0, largest 30.0; every recorded number the same in 0 of "
            "2; bit-identical parameters in 1 of 2 with parameters on both sides" in capsys.readouterr().out)


def test_a_results_file_is_compared_with_its_replay_by_every_recorded_number(tmp_path, capsys):
    """A committed results file has no parameters: its runs are matched by what they record."""
    a = _sweep(tmp_path / "a", [("bc-oh", {}, 0, 100.0), ("bc-oh", {}, 1, 90.0)], [[1.0], [2.0]])
    b = _sweep(tmp_path / "b", [("bc-oh", {}, 0, 100.0), ("bc-oh", {}, 1, 91.0)], [[1.0], [2.0]])
    rows = compare_runs.compare(a / "results.json", b)
    assert [(r["seed"], r["same_record"], r["param_max_abs_diff"]) for r in rows] == [(0, True, None), (1, False, None)]
    assert compare_runs.main([str(a / "results.json"), str(b)]) == 0
    assert "every recorded number the same in 1 of 2; bit-identical parameters in 0 of 0" in capsys.readouterr().out


def test_folders_that_are_not_sweeps_or_share_nothing_are_refused(tmp_path, capsys):
    a = _sweep(tmp_path / "a", [("bc-oh", {}, 0, 100.0)], [[1.0]])
    b = _sweep(tmp_path / "b", [("bc-oh", {}, 1, 100.0)], [[1.0]])
    for argv, message in (([str(tmp_path), str(a)], "is not a finished sweep's --out folder"),
                          ([str(a), str(b)], "the two sweeps share no run")):
        with pytest.raises(SystemExit) as exit_:
            compare_runs.main(argv)
        assert exit_.value.code == 2 and message in capsys.readouterr().err
