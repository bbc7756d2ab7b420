"""Demonstrations: collection, split, files, cache and validation (ToyCar: no MJX compile)."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax.history import history_index
from ape_jax.pipeline import collect
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline.data import DataError, Demonstrations


@pytest.fixture(scope="module")
def car():
    return envs.make("toycar", obs="full")


@pytest.fixture(scope="module")
def demos(car):
    return collect.collect(car, car.expert, jax.random.PRNGKey(0), num_episodes=5, batch=3)


@pytest.fixture(scope="module")
def noisy(car):
    return collect.collect(car, car.expert, jax.random.PRNGKey(1), num_episodes=3, noise_frac=0.5, noise_std=0.5)


@pytest.mark.parametrize("chunk", [64, 300])
def test_collection_in_chunks_has_the_whole_episode_programs_rows_and_stops_once_every_episode_ended(car, chunk):
    """`collect` runs jitted chunks of steps (a Ctrl-C waits for one chunk, not a batch's whole episodes): the
    rows, labels, simulator states and final states are bit for bit those of one whole-episode program."""
    key = jax.random.PRNGKey(5)
    whole = jax.device_get(collect.make_batch_collector(car, car.expert, 4, 0.3, 0.5, 3)(key))
    chunked = collect.make_chunked_collector(car, car.expert, 4, 0.3, 0.5, 3, chunk=chunk)(key)
    steps = chunked.valid.shape[1]
    assert steps < car.episode_length or chunk == car.episode_length   # stopped early: all ended by then
    assert not np.asarray(whole.valid)[:, steps:].any()   # what the chunks left out was outside every episode
    cut = jax.tree.map(lambda x: np.asarray(x)[:, :steps], whole.replace(final=None))
    for a, b in zip(jax.tree.leaves(cut), jax.tree.leaves(chunked.replace(final=None)), strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(jax.tree.leaves(whole.final), jax.tree.leaves(chunked.final), strict=True):
        np.testing.assert_array_equal(a, b)


def test_collected_transitions_have_consistent_shapes_and_episode_boundaries(car, demos):
    n = len(demos)
    assert demos.obs.shape == (n, 5) and demos.obs.dtype == np.float32
    assert demos.action.shape == demos.executed.shape == (n, 2)
    assert demos.sim["x"].shape == (n,) and demos.sim["key"].shape == (n, 2)
    assert list(demos.episode_ids) == [0, 1, 2, 3, 4]  # the padded last batch was trimmed
    starts = np.flatnonzero(np.r_[True, np.diff(demos.episode) != 0])
    assert np.all(demos.t[starts] == 0) and np.all(np.diff(demos.t)[np.diff(demos.episode) == 0] == 1)
    ends = np.r_[starts[1:] - 1, n - 1]
    # every ToyCar expert episode reaches the end of the road: done exactly at its last step
    assert np.all(demos.done[ends] == 1) and demos.done.sum() == demos.num_episodes
    np.testing.assert_array_equal(demos.action, demos.executed)  # no noise requested


def test_observations_can_be_recomputed_from_the_recorded_simulator_state(car, demos):
    reobserved = jax.jit(jax.vmap(car.observe_sim))(jax.tree.map(jnp.asarray, demos.sim))
    np.testing.assert_allclose(np.asarray(reobserved), demos.obs, rtol=1e-6)  # XLA may fuse differently


def test_noise_injection_perturbs_executed_actions_and_keeps_clean_labels(car, noisy):
    clean = jax.vmap(car.expert)(jax.vmap(envs.toycar.full_observation)(
        envs.toycar.ToyCarSim(**jax.tree.map(jnp.asarray, noisy.sim))))
    np.testing.assert_array_equal(np.asarray(clean), noisy.action)
    perturbed = np.any(noisy.executed != noisy.action, axis=1).mean()
    assert 0.3 < perturbed < 0.7  # noise_frac=0.5
    low, high = car.action_bounds
    assert np.all(noisy.executed >= np.asarray(low)) and np.all(noisy.executed <= np.asarray(high))


def test_split_is_by_episode_without_leakage(demos):
    train, val = demos.split(val_frac=0.2, seed=3)
    assert set(train.episode_ids).isdisjoint(val.episode_ids)
    assert sorted([*train.episode_ids, *val.episode_ids]) == list(range(5))
    assert val.num_episodes == 1 and len(train) + len(val) == len(demos)
    assert demos.split(0.2, seed=3).val.episode_ids.tolist() == val.episode_ids.tolist()  # reproducible


def test_history_index_pads_episode_starts_with_the_first_step():
    t = jnp.array([0, 1, 2, 3, 0, 1])
    np.testing.assert_array_equal(history_index(t, jnp.array([0, 2, 3, 5]), 3),
                                  [[0, 0, 0], [0, 1, 2], [1, 2, 3], [4, 4, 5]])
    # previous actions only (offset 1): row 0 of an episode sees its first step
    np.testing.assert_array_equal(history_index(t, jnp.array([2, 4]), 2, offset=1), [[0, 1], [4, 4]])


def test_save_and_load_round_trip_bit_exact(tmp_path, noisy):
    meta = data_lib.save(tmp_path / "d.npz", noisy, {"env": "toycar", "obs": "full"})
    loaded, meta2 = data_lib.load(tmp_path / "d.npz")
    assert meta2 == meta and meta["num_transitions"] == len(noisy) and meta["obs_shape"] == [5]
    for a, b in zip(jax.tree.leaves(noisy), jax.tree.leaves(loaded)):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)


def _arrays(demos):
    return {k: np.asarray(v).copy() for k, v in data_lib._flat(demos).items()}


def _write_raw(path, arrays, meta):
    np.savez_compressed(path, **arrays)
    path.with_suffix(".json").write_text(json.dumps(meta))


@pytest.mark.parametrize("corrupt, message", [
    (lambda a: a.pop("action"), "missing keys \\['action'\\]"),
    (lambda a: a.__setitem__("reward", a["reward"][:-1]), "mismatched lengths"),
    (lambda a: a["obs"].__setitem__((3, 1), np.nan), "'obs' has non-finite values in 1 rows \\(first: 3\\)"),
    (lambda a: a.__setitem__("obs", a["obs"][:, :4]), "rows have shape \\[4\\], the metadata says \\[5\\]"),
    (lambda a: a["t"].__setitem__(4, 7), "time index breaks at row 4"),
    (lambda a: a.__setitem__("episode", np.r_[a["episode"][a["episode"] != 0], a["episode"][a["episode"] == 0]]),
     "time index breaks|not contiguous"),
    (lambda a: a.__setitem__("action", a["action"][:, 0]), "'action' must be a \\[N, A\\] float array"),
])
def test_load_refuses_inconsistent_arrays_naming_the_file(tmp_path, demos, corrupt, message):
    arrays = _arrays(demos)
    corrupt(arrays)
    path = tmp_path / "bad.npz"
    _write_raw(path, arrays, {"obs_shape": [5], "action_size": 2})
    with pytest.raises(DataError, match=message) as err:
        data_lib.load(path)
    assert str(path) in str(err.value)


def test_load_refuses_truncated_changed_or_incomplete_files(tmp_path, demos):
    path = tmp_path / "d.npz"
    data_lib.save(path, demos, {"env": "toycar"})
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DataError, match="SHA-256 mismatch"):
        data_lib.load(path)
    meta = json.loads(path.with_suffix(".json").read_text())
    del meta["sha256"]  # a hand-written dataset has no checksum: the zip reader must still notice
    path.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="truncated or unreadable"):
        data_lib.load(path)
    path.with_suffix(".json").unlink()
    with pytest.raises(DataError, match="d.npz: corrupt: not a readable .npz archive"):  # not "metadata missing"
        data_lib.load(path)
    path.write_bytes(raw)   # whole, without its metadata: that is what is missing
    with pytest.raises(DataError, match="metadata d.json is missing"):
        data_lib.load(path)
    with pytest.raises(DataError, match="no such dataset file"):
        data_lib.load(tmp_path / "none.npz")


def test_image_datasets_stay_uint8_and_reject_float_frames(tmp_path):
    car = envs.make("toycar", obs="image", image_size=16)
    d = collect.collect(car, car.expert, jax.random.PRNGKey(2), num_episodes=1)
    assert d.obs.dtype == np.uint8 and d.obs.shape[1:] == (16, 16, 3)
    np.testing.assert_array_equal(np.asarray(jax.jit(jax.vmap(car.observe_sim))(jax.tree.map(jnp.asarray, d.sim))),
                                  d.obs)
    arrays = _arrays(d)
    arrays["obs"] = arrays["obs"].astype(np.float32)
    _write_raw(tmp_path / "f.npz", arrays, {"obs": "image"})
    with pytest.raises(DataError, match="image observations must be uint8"):
        data_lib.load(tmp_path / "f.npz")


def test_cache_collects_once_and_keys_on_every_setting(tmp_path):
    cfg = collect.data_key("toycar", "full", episodes=2, seed=4)
    first, meta, path, cached = collect.collect_cached(cfg, tmp_path)
    assert not cached and path.parent == tmp_path and meta["settings"]["episodes"] == 2
    again, _, path2, cached2 = collect.collect_cached(cfg, tmp_path)
    assert cached2 and path2 == path
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(again)):
        np.testing.assert_array_equal(a, b)
    other = collect.data_key("toycar", "full", episodes=2, seed=4, noise_frac=0.1, noise_std=0.2)
    assert data_lib.cache_path(tmp_path, other) != path
    assert data_lib.cache_path(tmp_path, collect.data_key("toycar", "full", episodes=3, seed=4)) != path
    # a rule-based expert's settings (ToyCar's physics) are part of the key, so a changed default is new data
    assert cfg["expert"]["config"]["rolling_resistance"] == envs.toycar.ToyCarConfig().rolling_resistance
    changed = json.loads(json.dumps(cfg))
    changed["expert"]["config"]["rolling_resistance"] = 0.0
    assert data_lib.cache_path(tmp_path, changed) != path


def test_demonstrations_is_a_pytree_that_jit_can_index(demos):
    picked = jax.jit(lambda d, i: d.action[history_index(d.t, i, 2)])(
        jax.tree.map(jnp.asarray, demos), jnp.array([0, 1]))
    assert picked.shape == (2, 2, 2)
    assert isinstance(demos.take(np.arange(3)), Demonstrations)


@pytest.mark.parametrize("obs", ["pos", "image"])
@pytest.mark.integration
def test_mujoco_collection_records_every_mode_and_a_reobservable_state(obs):
    env = envs.make("hopper", obs=obs, episode_length=30, image_size=16)
    expert = lambda full: jnp.tanh(full[5:8])  # noqa: E731  a stand-in: the shipped expert is tested elsewhere
    d = collect.collect(env, expert, jax.random.PRNGKey(0), num_episodes=2)
    assert d.obs.shape == (len(d), *env.observation_shape) and d.obs.dtype == env.observation_dtype
    assert d.sim["qpos"].shape == (len(d), 6) and d.sim["qvel"].shape == (len(d), 6)
    # jitted: MJX's mj_forward run op by op under vmap takes ~10x longer than compiling it
    again = np.asarray(jax.jit(jax.vmap(env.observe_sim))(jax.tree.map(jnp.asarray, d.sim)))
    if obs == "pos":
        # joint angles come straight from qpos; Brax's torso height (dim 0) is read from body
        # poses computed before the last physics substep, so re-observing moves it slightly
        np.testing.assert_allclose(again[:, 1:], d.obs[:, 1:], atol=1e-5)
        np.testing.assert_allclose(again[:, 0], d.obs[:, 0], atol=0.02)
    else:
        assert np.abs(again.astype(int) - d.obs).mean() < 8  # the same scene, up to that substep


def test_collect_summarises_rare_actions_per_dimension():
    """ToyCar-like data: the brake is pressed in 5 steps of one episode out of 4; the throttle never varies."""
    from types import SimpleNamespace

    from experiments.collect import action_summary

    action = np.zeros((100, 2), np.float32)
    action[:, 0] = 1.0
    action[60:65, 1] = 1.0
    demos = SimpleNamespace(action=action, episode=np.repeat(np.arange(4), 25), num_episodes=4)
    lines = action_summary(demos).splitlines()
    assert lines[0] == "action 0: mean 1.000, std 0.000; beyond 2 std in 0 of 100 steps (0.0%), in 0 of 4 episodes"
    assert lines[1].startswith("action 1: mean 0.050, std 0.218; beyond 2 std in 5 of 100 steps (5.0%), in 1 of 4")
