"""Action statistics (`ape_jax.experts.stats`, `experiments.expert_stats`): hand-computed values on a tiny sequence,
ψ's held-out error on sequences with a known answer, and bad input refused."""

import jax
import numpy as np
import pytest

from ape_jax.experts import stats
from experiments import expert_stats

# two episodes of 2-dim labels: [[0, 0], [1, 0], [1, 2]] and [[2, -2], [0, 0]]
ACTIONS = np.array([[0, 0], [1, 0], [1, 2], [2, -2], [0, 0]], np.float32)
EPISODE = np.array([0, 0, 0, 1, 1])
T = np.array([0, 1, 2, 0, 1])


def test_the_statistics_of_a_tiny_sequence_match_hand_computed_values():
    # entries outside [-1, 1]: 2 (row 3), 2 and -2 (row 4): 3 of 10
    assert stats.outside_share(ACTIONS) == pytest.approx(0.3)
    assert stats.outside_share(ACTIONS, -2.0, 2.0) == 0.0
    assert stats.outside_share(ACTIONS, np.array([-1.0, -3.0]), np.array([1.0, 3.0])) == pytest.approx(0.1)
    # within episodes: |(1,0)-(0,0)|² = 1, |(1,2)-(1,0)|² = 4, |(0,0)-(2,-2)|² = 8; the step across episodes is not
    # a copy (|(2,-2)-(1,2)|² = 17 would make the mean 7.5)
    assert stats.copy_previous_error(ACTIONS, EPISODE, T) == pytest.approx(13 / 3)
    # per dim: (0, 1, 1, 2, 0) has variance 0.56, (0, 0, 2, -2, 0) 1.6
    assert stats.action_variance(ACTIONS) == pytest.approx(2.16)
    assert np.isnan(stats.copy_previous_error(ACTIONS[:2], np.array([0, 1]), np.array([0, 0])))


def _episodes(rows_per_episode: int, episodes: int, make) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    actions = np.concatenate([make(rng, rows_per_episode) for _ in range(episodes)]).astype(np.float32)
    episode = np.repeat(np.arange(episodes), rows_per_episode)
    t = np.tile(np.arange(rows_per_episode), episodes)
    return actions, episode, t


def test_psi_predicts_a_smooth_expert_and_not_white_noise():
    smooth = lambda rng, n: np.stack([np.sin(0.2 * np.arange(n) + rng.uniform(0, 6))] * 2, -1)  # noqa: E731
    noise = lambda rng, n: rng.normal(0.0, 1.0, (n, 2))  # noqa: E731
    out = {}
    for name, make in (("smooth", smooth), ("noise", noise)):
        actions, episode, t = _episodes(100, 20, make)
        perm = np.random.default_rng(1).permutation(len(actions))
        out[name] = stats.action_stats(jax.random.PRNGKey(0), actions, episode, t, np.sort(perm[:1500]),
                                       np.sort(perm[1500:]), psi_steps=300)
    smooth_, noise_ = out["smooth"], out["noise"]
    assert smooth_.psi_error < 0.05 * smooth_.variance, smooth_
    assert 0.7 * noise_.variance < noise_.psi_error < 1.5 * noise_.variance, noise_   # nothing to predict from
    assert noise_.copy_error == pytest.approx(2 * noise_.variance, rel=0.15)          # E|a - a'|² = 2 Var
    assert (smooth_.rows, smooth_.psi_train_rows, smooth_.psi_val_rows) == (2000, 1500, 500)


def test_the_table_prints_every_column():
    entry = dict(return_mean=1234.5, outside=0.25, copy_error=0.1234, psi_error=0.0456, variance=1.5)
    text = expert_stats.table({"hopper-rough": entry})
    assert "| hopper-rough | 1,234.5 | 0.250 | 0.1234 | 0.0456 | 1.500 |" in text


@pytest.mark.parametrize("argv, message", [
    (["--env", "nope"], "unknown env 'nope'"),
    (["--env", "toycar"], "unknown env 'toycar'"),
    (["--env", "hopper", "--expert", "nosuch"], "no shipped or imported expert 'hopper-nosuch'"),
    (["--env", "hopper", "--dir", "/nonexistent"], "--dir /nonexistent does not exist"),
    (["--env", "hopper", "--dir", "/"], "--dir /: no card.json there"),
    (["--env", "hopper", "--protocol", "nope"], "unknown protocol"),
    (["--env", "hopper", "--psi-steps", "0"], "must be >= 1"),
])
def test_expert_stats_refuses_bad_input_with_exit_code_2(argv, message, capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        expert_stats.main([*argv, "--out", str(tmp_path / "stats.json")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "stats.json").exists()
