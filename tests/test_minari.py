"""Minari datasets: exact round trip with `Demonstrations`, others' datasets, refusals, the collect export."""

import json

import gymnasium as gym
import minari
import numpy as np
import pytest

from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline import minari_io
from ape_jax.pipeline.data import DataError, Demonstrations
from experiments import collect as collect_cli

FIELDS = ("obs", "action", "executed", "episode", "t", "done", "reward")


def hand_demos(obs_shape=(4,), obs_dtype=np.float32, lengths=(9, 1, 14), ids=(3, 5, 9), seed=0) -> Demonstrations:
    """Episodes `ids` of `lengths` steps; the first terminates, the others are cut; some executed actions noisy."""
    rng = np.random.default_rng(seed)
    n = sum(lengths)
    obs = (rng.integers(0, 256, (n, *obs_shape), dtype=np.uint8) if obs_dtype == np.uint8
           else rng.normal(size=(n, *obs_shape)).astype(np.float32))
    action = rng.uniform(0, 1, (n, 2)).astype(np.float32)
    executed = np.where(rng.uniform(size=(n, 1)) < 0.3, np.clip(action + 0.1, 0, 1), action).astype(np.float32)
    done = np.zeros(n, np.float32)
    done[lengths[0] - 1] = 1.0
    return Demonstrations(
        obs=obs, action=action, executed=executed,
        episode=np.repeat(np.asarray(ids, np.int32), lengths),
        t=np.concatenate([np.arange(k, dtype=np.int32) for k in lengths]),
        done=done, reward=rng.normal(size=n).astype(np.float32))


def assert_same(a: Demonstrations, b: Demonstrations):
    for k in FIELDS:
        x, y = np.asarray(getattr(a, k)), np.asarray(getattr(b, k))
        assert x.dtype == y.dtype, k
        np.testing.assert_array_equal(x, y, err_msg=k)


@pytest.mark.parametrize("obs_shape, obs_dtype", [((4,), np.float32), ((32, 32, 3), np.uint8)])
def test_round_trip_is_exact_and_minari_reads_the_dataset(tmp_path, obs_shape, obs_dtype):
    # 32x32 uint8 frames are what Minari JPEG-encodes by default: exactness shows that is off
    demos = hand_demos(obs_shape, obs_dtype)
    path = minari_io.to_minari(demos, {"env": "hand", "seed": 0}, "hand-v0", root=tmp_path, action_bounds=(0.0, 1.0))
    assert path == tmp_path / "hand-v0"
    loaded = minari_io.from_minari(path)
    assert_same(demos, loaded)
    assert loaded.sim == {}
    assert_same(demos, minari_io.from_minari("hand-v0", root=tmp_path))  # by id under a root

    ds = minari.MinariDataset(path / "data")
    assert ds.total_episodes == 3 and ds.total_steps == len(demos)
    assert ds.storage.metadata["ape_jax"] == {"env": "hand", "seed": 0}
    assert ds.action_space == gym.spaces.Box(0.0, 1.0, (2,), np.float32)
    expected_obs = (gym.spaces.Box(0, 255, obs_shape, np.uint8) if obs_dtype == np.uint8
                    else gym.spaces.Box(-np.inf, np.inf, obs_shape, np.float32))
    assert ds.observation_space == expected_obs
    first, single, last = ds.iterate_episodes()
    assert len(first.observations) == 10 and len(first.actions) == 9  # T + 1 observations
    np.testing.assert_array_equal(first.observations[-1], first.observations[-2])  # the last one repeated
    assert first.terminations[-1] and not first.truncations.any()
    assert not last.terminations.any() and last.truncations[-1] and last.truncations.sum() == 1
    assert len(single.rewards) == 1 and single.truncations[0]


def test_unbounded_action_space_when_actions_leave_the_given_bounds(tmp_path):
    demos = hand_demos()
    path = minari_io.to_minari(demos, None, "wide-v0", root=tmp_path, action_bounds=(0.0, 0.5))
    space = minari.MinariDataset(path / "data").action_space
    assert np.all(np.isinf(space.low)) and np.all(np.isinf(space.high))


def test_namespaced_ids_load_with_minaris_own_functions_and_existing_ids_are_kept(tmp_path, monkeypatch):
    demos = hand_demos()
    path = minari_io.to_minari(demos, {}, "ape_jax/toy/hand-v1", root=tmp_path)
    assert path == tmp_path / "ape_jax" / "toy" / "hand-v1"
    assert [p.name for p in tmp_path.iterdir()] == ["ape_jax"]  # the staging directory is gone
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert list(minari.list_local_datasets()) == ["ape_jax/toy/hand-v1"]
    assert minari.load_dataset("ape_jax/toy/hand-v1").total_steps == len(demos)
    assert_same(demos, minari_io.from_minari("ape_jax/toy/hand-v1"))  # the root from the environment

    with pytest.raises(FileExistsError, match="exists already"):
        minari_io.to_minari(demos, {}, "ape_jax/toy/hand-v1", root=tmp_path)
    other = hand_demos(seed=1)
    minari_io.to_minari(other, {}, "ape_jax/toy/hand-v1", root=tmp_path, overwrite=True)
    assert_same(other, minari_io.from_minari(path))
    with pytest.raises(ValueError, match="invalid Minari dataset id 'hand'"):
        minari_io.to_minari(demos, {}, "hand", root=tmp_path)  # Minari ids carry a version


def test_a_dataset_recorded_with_minaris_data_collector_loads(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    env = minari.DataCollector(gym.make("CartPole-v1", max_episode_steps=15))
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:  # a balancing controller: episodes reach the 15-step limit (truncation)
            obs, _, terminated, truncated, _ = env.step(int(obs[2] + 0.5 * obs[3] > 0))
            done = terminated or truncated
    with pytest.warns(UserWarning):
        env.create_dataset("cartpole/balance-v0", algorithm_name="rule")
    env.close()

    demos = minari_io.from_minari("cartpole/balance-v0")
    episodes = list(minari.load_dataset("cartpole/balance-v0").iterate_episodes())
    assert len(demos) == sum(len(ep) for ep in episodes) == 45
    assert demos.obs.shape == (45, 4) and demos.obs.dtype == np.float32
    np.testing.assert_array_equal(demos.obs, np.concatenate([ep.observations[:-1] for ep in episodes]))
    # Discrete(2) actions become one-hot labels
    np.testing.assert_array_equal(demos.action, np.eye(2)[np.concatenate([ep.actions for ep in episodes])])
    np.testing.assert_array_equal(demos.executed, demos.action)
    assert demos.episode_ids.tolist() == [0, 1, 2] and demos.t.tolist() == list(range(15)) * 3
    assert demos.done.sum() == 0 and np.all(demos.reward == 1.0)


def _dict_observation_dataset(root):
    space = gym.spaces.Dict({"pos": gym.spaces.Box(-1, 1, (2,), np.float32)})
    buffer = minari.data_collector.EpisodeBuffer(
        observations={"pos": np.zeros((4, 2), np.float32)}, actions=np.zeros((3, 1), np.float32),
        rewards=np.zeros(3), terminations=np.zeros(3, bool), truncations=np.r_[False, False, True])
    with pytest.MonkeyPatch.context() as mp, pytest.warns(UserWarning):
        mp.setenv("MINARI_DATASETS_PATH", str(root))
        minari.create_dataset_from_buffers("dict-v0", [buffer], observation_space=space,
                                           action_space=gym.spaces.Box(-1, 1, (1,), np.float32))
    return root / "dict-v0"


def _corrupt_metadata(root):
    path = minari_io.to_minari(hand_demos(), {}, "bad-v0", root=root)
    (path / "data" / "metadata.json").write_text("{not json")
    return path


def _truncated_hdf5(root):
    path = minari_io.to_minari(hand_demos(), {}, "bad-v0", root=root)
    h5 = path / "data" / "main_data.hdf5"
    h5.write_bytes(h5.read_bytes()[:2000])
    return path


def _non_finite(root):
    demos = hand_demos()
    demos.obs[11, 2] = np.nan
    return minari_io.to_minari(demos, {}, "nan-v0", root=root)


def _edit_metadata(edit):
    def make(root):
        path = minari_io.to_minari(hand_demos(), {}, "bad-v0", root=root)
        meta = path / "data" / "metadata.json"
        meta.write_text(json.dumps(edit(json.loads(meta.read_text()))))
        return path
    return make


def _a_file(root):
    (root / "x.npz").write_bytes(b"")
    return root / "x.npz"


@pytest.mark.parametrize("make, message", [
    (lambda root: root / "nowhere", "no such Minari dataset"),
    (lambda root: root, "not a Minari dataset \\(no data/metadata.json"),
    (_a_file, "not a Minari dataset \\(a file"),
    (_corrupt_metadata, "not a readable Minari dataset \\(JSONDecodeError"),
    (_truncated_hdf5, "unreadable Minari episodes"),
    (_non_finite, "'obs' has non-finite values in 1 rows \\(first: 11\\)"),
    (_dict_observation_dataset, "only Box observation spaces are supported, this dataset has Dict observations"),
    (_edit_metadata(lambda m: [m]), "not a Minari dataset \\(metadata.json holds a list, not an object\\)"),
    (_edit_metadata(lambda m: {k: v for k, v in m.items() if k not in ("action_space", "data_format")}),
     "not a Minari dataset \\(metadata.json lacks data_format, action_space\\)"),
    (_edit_metadata(lambda m: {**m, "data_format": "parquet9"}),
     "not a readable Minari dataset \\(KeyError: 'parquet9'"),
    (_edit_metadata(lambda m: {**m, "total_episodes": 99}), "unreadable Minari episodes \\(KeyError"),
])
def test_from_minari_refuses_bad_datasets_with_one_line_naming_the_path(tmp_path, make, message):
    path = make(tmp_path)
    with pytest.raises(DataError, match=message) as err:
        minari_io.from_minari(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_collect_format_minari_exports_the_collected_dataset(tmp_path, capsys):
    argv = ["--env", "toycar", "--obs", "full", "--episodes", "2", "--data-dir", str(tmp_path / "cache"),
            "--format", "minari", "--out", str(tmp_path / "minari")]
    assert collect_cli.main(argv) == 0
    out = capsys.readouterr().out
    (npz,) = (tmp_path / "cache").glob("*.npz")
    demos, _ = data_lib.load(npz)
    path = tmp_path / "minari" / f"{npz.stem}-v0"
    assert f"minari dataset: {path}" in out
    exported = minari_io.from_minari(path)
    assert len(exported) == len(demos) and exported.num_episodes == 2
    assert_same(demos, exported)
    bounds = minari.MinariDataset(path / "data").action_space
    np.testing.assert_array_equal(bounds.low, [0, 0])
    np.testing.assert_array_equal(bounds.high, [1, 1])
    assert "no reference scores: its expert is rule-based" in out
    assert collect_cli.main(argv) == 0 and "(exported before)" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (lambda root: ["--out", str(root)], "--out applies to --format minari only"),
    (lambda root: ["--format", "minari", "--out", str(root / "f")], "is a file; it must be a directory"),
    (lambda root: ["--format", "tfrecord"], "invalid choice: 'tfrecord'"),
])
def test_collect_refuses_bad_export_options_with_exit_code_2(tmp_path, argv, message, capsys):
    (tmp_path / "f").write_text("")
    with pytest.raises(SystemExit) as exc:
        collect_cli.main(["--env", "toycar", "--obs", "full", *argv(tmp_path)])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_reference_scores_make_minaris_normalised_score_the_tables_normalisation(tmp_path, monkeypatch):
    """`ref_min_score`/`ref_max_score` (the protocol's random policy and expert): Minari's own
    `get_normalized_score` then gives (return − random) ÷ (expert − random), as the project's tables do."""
    path = minari_io.to_minari(hand_demos(), {}, "toy/refs-v0", root=tmp_path, ref_min_score=-10.0, ref_max_score=90.0)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    dataset = minari.load_dataset("toy/refs-v0")
    np.testing.assert_allclose(minari.get_normalized_score(dataset, np.array([-10.0, 40.0, 90.0])), [0.0, 0.5, 1.0])
    assert_same(hand_demos(), minari_io.from_minari(path))   # the data are unchanged by the scores
    for kw, match in (({"ref_min_score": 1.0}, "both reference scores"), ({"ref_min_score": 1.0, "ref_max_score": 1.0},
                                                                          "must be finite and differ")):
        with pytest.raises(ValueError, match=match):
            minari_io.to_minari(hand_demos(), {}, "toy/bad-v0", root=tmp_path, **kw)
    without = minari_io.to_minari(hand_demos(), {}, "toy/plain-v0", root=tmp_path)
    with pytest.raises(ValueError, match="Reference score not provided"):
        minari.get_normalized_score(minari.MinariDataset(without / "data"), np.array([1.0]))


def test_the_reference_returns_are_the_protocols_normalisation_and_none_for_a_rule_based_expert():
    from ape_jax import tasks
    from ape_jax.pipeline import collect
    from envs import experts

    hopper = tasks.get("hopper")
    for name in ("fca", "brax"):
        ref = collect.reference_returns("hopper", hopper.protocol(name, "pos"))
        assert ref == experts.reference("hopper", name) and ref["return_mean"] > ref["random_return_mean"]
    assert collect.reference_returns("toycar", tasks.get("toycar").protocol(None, "full")) is None
