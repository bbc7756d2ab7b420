"""External experts (`envs.experts.imported`, `experiments.import_expert`), labels as the expert gave them or clipped
(`protocol.labels` in collection), and `--dataset` with its own expert (`collect.dataset_expert`).

Synthetic files of the CS294/FCA pickle's structure and of the .npz format stand in for real experts (the FCA
file has no licence: never in the repository)."""

import json
import pathlib
import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax.pipeline import collect, data, minari_io
from ape_jax.pipeline import sweep as S
from envs import experts
from envs.experts import imported
from experiments import expert_references, import_expert
from experiments import sweep as sweep_cli

HOPPER_D, HOPPER_A = 11, 3  # gym's (and Brax's) Hopper: qpos[1:] (5) and qvel (6); 3 torques


def _cs294(rng, d=HOPPER_D, a=HOPPER_A, hidden=(6, 5), names=("layer_0", "layer_2"), reverse=False):
    """A dict of the CS294 pickle's structure (tiny layers), float64 as the real file's; `reverse`: its hidden
    layers inserted last first (they apply in sorted name order)."""
    sizes = (d, *hidden)
    mean = rng.normal(size=(1, d))
    layers = [(n, {"AffineLayer": {"W": rng.normal(size=(i, o)), "b": rng.normal(size=(1, o))}})
              for n, i, o in zip(names, sizes[:-1], sizes[1:])]
    return {"nonlin_type": "tanh", "GaussianPolicy": {
        "obsnorm": {"Standardizer": {"mean_1_D": mean, "meansq_1_D": mean ** 2 + rng.uniform(0.5, 2, (1, d)),
                                     "count": np.array(1e5)}},
        "hidden": {"FeedforwardNet": dict(layers[::-1] if reverse else layers)},
        "out": {"AffineLayer": {"W": rng.normal(size=(hidden[-1], a)), "b": rng.normal(size=(1, a))}},
        "logstdevs_1_Da": np.zeros((1, a))}}


def _cs294_action(tree, obs):
    """CS294's load_policy, written out: the Gaussian's mean."""
    gp = tree["GaussianPolicy"]
    norm = gp["obsnorm"]["Standardizer"]
    std = np.sqrt(np.maximum(0, norm["meansq_1_D"] - norm["mean_1_D"] ** 2))
    x = (obs - norm["mean_1_D"]) / (std + 1e-6)
    for name in sorted(gp["hidden"]["FeedforwardNet"]):
        layer = gp["hidden"]["FeedforwardNet"][name]["AffineLayer"]
        x = np.tanh(x @ layer["W"] + layer["b"])
    return x @ gp["out"]["AffineLayer"]["W"] + gp["out"]["AffineLayer"]["b"]


def _write_pickle(path, tree, numpy1_names=True):
    raw = pickle.dumps(tree, protocol=2)
    if numpy1_names:  # the real file names numpy 1's module (numpy 2 renamed numpy.core to numpy._core)
        raw = raw.replace(b"numpy._core.multiarray\n", b"numpy.core.multiarray\n")
    path.write_bytes(raw)
    return path


def _npz(rng, d=HOPPER_D, a=HOPPER_A, hidden=(6,), head="linear", drop=()):
    sizes = (d, *hidden, a)
    arrays = {"obs_mean": rng.normal(size=d), "obs_std": rng.uniform(0.5, 2, d), "activation": np.array("tanh"),
              "head": np.array(head)}
    for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        arrays[f"kernel_{i}"], arrays[f"bias_{i}"] = rng.normal(size=(n_in, n_out)), rng.normal(size=n_out)
    return {k: v for k, v in arrays.items() if k not in drop}


@pytest.fixture
def expert_dir(tmp_path, monkeypatch):
    root = tmp_path / "experts"
    monkeypatch.setenv("APE_JAX_EXPERTS", str(root))
    return root


@pytest.fixture
def no_measuring(monkeypatch):
    """`import_expert` without its reference rollouts (minutes of compiling MJX): fixed references."""
    calls = []

    def measure(env_name, protocol, policy, episodes, seed, command):
        calls.append((protocol.name, episodes))
        jax.jit(policy)(jnp.zeros(HOPPER_D))  # it acts under jit on the full observation
        return {"episodes": episodes, "return_mean": 100.0, "return_std": 1.0, "random_return_mean": 10.0,
                "random_return_std": 2.0, "protocol": {"name": protocol.name}, "command": command, "seconds": 0.0}

    monkeypatch.setattr(expert_references, "measure", measure)
    return calls


def _refused(main, argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# -- reading files -----------------------------------------------------------------------------------------------

def test_the_cs294_pickle_converts_to_the_policy_cs294_computes(tmp_path):
    rng = np.random.default_rng(0)
    tree = _cs294(rng, reverse=True)  # applied in sorted name order, whatever the dict's order
    got = imported.read(_write_pickle(tmp_path / "e.pkl", tree))
    assert (got.obs_size, got.hidden, got.action_size, got.activation, got.head) == (11, [6, 5], 3, "tanh", "linear")
    obs = rng.normal(size=(7, HOPPER_D))
    policy = jax.jit(experts.policy_from_params(got.params, got.activation, got.head))
    np.testing.assert_allclose(policy(obs), _cs294_action(tree, obs), rtol=1e-4, atol=1e-4)
    assert np.abs(_cs294_action(tree, obs)).max() > 1   # unbounded labels, as the real expert's


def test_the_restricted_unpickler_refuses_anything_but_arrays_and_plain_containers(tmp_path):
    marker = tmp_path / "executed"

    class Payload:
        def __reduce__(self):
            return pathlib.Path.touch, (marker,)

    for obj, named in (({"nonlin_type": "tanh", "x": Payload()}, "it names"),
                       ({"a": np.array([object()], dtype=object)}, "Python objects"),
                       ({"a": np.float64(1.0)}, "scalar")):
        path = tmp_path / "bad.pkl"
        path.write_bytes(pickle.dumps(obj, protocol=2))
        with pytest.raises(imported.ImportError_, match=f"only numpy arrays and plain containers.*{named}"):
            imported.read(path, "cs294-pickle")
    assert not marker.exists()   # refused, never executed
    assert imported.safe_unpickle(pickle.dumps({"a": [np.arange(3), ("x", 1.5, None)]}))["a"][1] == ("x", 1.5, None)


def test_the_npz_format_converts_and_missing_layers_are_refused(tmp_path):
    rng = np.random.default_rng(1)
    arrays = _npz(rng, hidden=(6, 4))
    np.savez(tmp_path / "e.npz", **arrays)
    got = imported.read(tmp_path / "e.npz")
    obs = rng.normal(size=(5, HOPPER_D))
    x = (obs - arrays["obs_mean"]) / arrays["obs_std"]
    x = np.tanh(np.tanh(x @ arrays["kernel_0"] + arrays["bias_0"]) @ arrays["kernel_1"] + arrays["bias_1"])
    want = x @ arrays["kernel_2"] + arrays["bias_2"]
    np.testing.assert_allclose(experts.policy_from_params(got.params, got.activation, got.head)(obs), want,
                               rtol=1e-4, atol=1e-4)
    # a tanh head of A outputs: tanh of them (padded to the shipped form, 2A outputs with the mean first)
    np.savez(tmp_path / "t.npz", **{**arrays, "head": np.array("tanh")})
    got = imported.read(tmp_path / "t.npz", action_size=HOPPER_A)
    assert got.action_size == HOPPER_A and got.params["kernels"][-1].shape == (4, 2 * HOPPER_A)
    np.testing.assert_allclose(experts.policy_from_params(got.params, got.activation, got.head)(obs), np.tanh(want),
                               rtol=1e-4, atol=1e-4)
    for drop, missing in ((("bias_1",), "bias_1"), (("kernel_1", "bias_1"), "kernel_1"), (("obs_std",), "obs_std")):
        np.savez(tmp_path / "m.npz", **_npz(rng, hidden=(6, 4), drop=drop))
        with pytest.raises(imported.ImportError_, match=f"missing layers or keys.*{missing}"):
            imported.read(tmp_path / "m.npz")


# -- the command line ---------------------------------------------------------------------------------------------

def test_import_writes_the_expert_outside_the_repository_and_the_pipeline_finds_it(tmp_path, expert_dir, no_measuring,
                                                                                  capsys):
    rng = np.random.default_rng(2)
    tree = _cs294(rng)
    path = _write_pickle(tmp_path / "Hopper-v1.pkl", tree)
    assert import_expert.main([str(path), "--env", "hopper", "--name", "mine"]) == 0
    # the task's mujoco-state and brax, the budget's episodes
    assert sorted(no_measuring) == [("brax", 10), ("mujoco-state", 20)]
    home = expert_dir / "hopper-mine"
    card = json.loads((home / "card.json").read_text())
    digest = imported.sha256(path)
    assert card["source"] == {"path": str(path.absolute()), "format": "cs294-pickle", "bytes": path.stat().st_size,
                              "sha256": digest}
    assert card["network"] == {"obs_size": 11, "hidden": [6, 5], "action_size": 3, "activation": "tanh",
                               "head": "linear"}
    assert experts.directory("hopper-mine") == home and experts.imported_names() == ("hopper-mine",)
    assert experts.reference("hopper-mine", "brax")["return_mean"] == 100.0   # references.json holds brax too
    assert experts.reference("hopper-mine", "mujoco-state")["random_return_mean"] == 10.0
    obs = rng.normal(size=(4, HOPPER_D))
    np.testing.assert_allclose(jax.jit(experts.load("hopper-mine"))(obs), _cs294_action(tree, obs), rtol=1e-4,
                               atol=1e-4)
    # collection names it by its file's SHA-256, so demonstrations of another file are another dataset
    cfg = collect.data_key("hopper", "pos", 2, expert="mine")
    assert cfg["expert"]["kind"] == "imported" and cfg["expert"]["sha256"] == digest
    assert collect.ExpertRef.of_key(cfg).variant == "mine" and collect.variant_of("hopper", cfg["expert"]) == "mine"
    assert "protocol.expert=mine" in capsys.readouterr().out


@pytest.mark.integration
def test_import_refuses_bad_input_and_writes_nothing(tmp_path, expert_dir, no_measuring, capsys):
    rng = np.random.default_rng(3)
    small = _write_pickle(tmp_path / "small.pkl", _cs294(rng, d=7))
    err = _refused(import_expert.main, [str(small), "--name", "x"], capsys)
    assert "reads 7 inputs" in err and "full observation" in err and "has 11" in err
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(pickle.dumps({"x": pathlib.Path("/")}, protocol=2))
    assert "only numpy arrays and plain containers" in _refused(import_expert.main, [str(bad), "--name", "x"], capsys)
    np.savez(tmp_path / "gap.npz", **_npz(rng, hidden=(6, 4), drop=("kernel_1",)))
    assert "missing layers" in _refused(import_expert.main, [str(tmp_path / "gap.npz"), "--name", "x"], capsys)
    good = _write_pickle(tmp_path / "good.pkl", _cs294(rng))
    assert "is a shipped expert" in _refused(import_expert.main, [str(good), "--name", "ppo"], capsys)
    assert "lowercase" in _refused(import_expert.main, [str(good), "--name", "My-Expert"], capsys)
    assert not no_measuring and not expert_dir.exists()  # refused before measuring, nothing written
    # a name taken by another file is kept unless --force
    assert import_expert.main([str(good), "--name", "x"]) == 0
    other = _write_pickle(tmp_path / "other.pkl", _cs294(rng))
    assert "imported already from another file" in _refused(import_expert.main, [str(other), "--name", "x"], capsys)
    assert import_expert.main([str(other), "--name", "x", "--force"]) == 0
    assert experts.card("hopper-x")["source"]["sha256"] == imported.sha256(other)


def test_the_fca_file_is_recognised_by_its_sha256():
    known = imported.KNOWN["56145a42b49fa5d7ca20bdc30407752a0830ee4cae882eccfd01e4fdddc4cf92"]
    assert "AlvinWen428/fighting-copycat-agents" in known["origin"] and known["env"] == "hopper"


# -- labels -------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def toycar():
    return envs.make("toycar", obs="full", episode_length=40, road_length=30.0, light_range=(12.0, 20.0))


def test_labels_are_clipped_or_raw_and_the_executed_action_is_clipped_either_way(toycar):
    loud = lambda obs: 3.0 * toycar.expert(obs) - 1.0   # noqa: E731  outside [0, 1]: -1 or 2
    key = jax.random.PRNGKey(0)
    raw = collect.collect(toycar, loud, key, 2, labels="raw")
    clipped = collect.collect(toycar, loud, key, 2)
    assert raw.action.min() == -1.0 and raw.action.max() == 2.0
    np.testing.assert_array_equal(clipped.action, np.clip(raw.action, 0, 1))
    for demos in (raw, clipped):
        np.testing.assert_array_equal(demos.executed, np.clip(raw.action, 0, 1))
    stats = collect.label_statistics(raw.action, toycar.action_bounds)
    assert stats["raw_outside_share"] == 1.0 and (stats["raw_min"], stats["raw_max"]) == (-1.0, 2.0)


def test_labels_name_the_data_only_when_raw_and_the_metadata_records_them(toycar, tmp_path):
    clipped = collect.data_key("toycar", "full", 2, episode_length=40)
    raw = collect.data_key("toycar", "full", 2, labels="raw", episode_length=40)
    assert "labels" not in clipped and raw["labels"] == "raw"   # the names of earlier datasets stay valid
    assert data.cache_path(tmp_path, clipped) != data.cache_path(tmp_path, raw)
    class Louder:   # the rule's action × 1.5: raw labels beyond the action range
        def policy(self, env):
            return lambda obs: 1.5 * env.expert(obs)

    demos, meta, _, _ = collect.collect_cached(raw, tmp_path, references={"return_mean": 5.0}, expert=Louder())
    assert meta["labels"]["mode"] == "raw" and 0 < meta["labels"]["raw_outside_share"] < 1
    assert demos.action.max() == 1.5 and demos.executed.max() == 1.0
    assert meta["references"] == {"return_mean": 5.0}
    demos, meta, _, _ = collect.collect_cached(clipped, tmp_path, expert=Louder())
    assert meta["labels"]["mode"] == "clipped" and meta["labels"]["raw_outside_share"] > 0
    assert demos.action.max() == 1.0


def test_dagger_executes_the_experts_action_clipped_and_records_its_label(toycar):
    from ape_jax.baselines import dagger
    from ape_jax.learner import LearnerConfig

    seen = []

    class Spy:
        """`toycar`, recording the actions its step is given."""

        def __init__(self, env):
            self.inner, self.name, self.obs_mode = env, env.name, env.obs_mode

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def step(self, state, action):
            jax.debug.callback(lambda a: seen.append(np.asarray(a)), action)
            return self.inner.step(state, action)

    env = Spy(toycar)
    cfg = LearnerConfig(obs_shape=(5,), action_dim=2, history=2, iterations=2, batch_size=4, loss="l1")
    params = cfg.model().init(jax.random.PRNGKey(0), jnp.zeros((1, 2 * 5)))  # the history, flattened
    loud = lambda obs: 3.0 * toycar.expert(obs) - 1.0   # noqa: E731
    records = jax.jit(lambda p, k: dagger.label_rollout(cfg, env, loud, None, None, p, k, 1.0, 2, 30))(
        params, jax.random.PRNGKey(1))
    jax.effects_barrier()
    assert float(records.action.min()) == -1.0 and float(records.action.max()) == 2.0   # labels as the expert gave
    executed = np.concatenate([np.reshape(a, (-1, 2)) for a in seen])
    assert executed.min() >= 0.0 and executed.max() <= 1.0   # what the environment executed: clipped


# -- --dataset with its own expert --------------------------------------------------------------------------------

def _dataset(path, obs_dim, action, meta, lengths=(30, 30, 30)):
    n = sum(lengths)
    episode = np.concatenate([np.full(k, i) for i, k in enumerate(lengths)]).astype(np.int32)
    t = np.concatenate([np.arange(k) for k in lengths]).astype(np.int32)
    rng = np.random.default_rng(0)
    demos = data.Demonstrations(obs=rng.normal(size=(n, obs_dim)).astype(np.float32),
                                action=np.broadcast_to(np.asarray(action, np.float32), (n, len(action))).copy(),
                                executed=np.zeros((n, len(action)), np.float32), episode=episode, t=t,
                                done=np.zeros(n, np.float32), reward=np.ones(n, np.float32), sim={})
    data.save(path, demos, meta)
    return path


TOYCAR_ARGS = ["--env", "toycar", "--obs", "full", "--iterations", "4", "--eval-episodes", "2", "--seeds", "1",
               "--quiet", "--set", "recipe.batch_size=8"]


def test_a_dataset_with_raw_labels_needs_the_protocols_consent(tmp_path, capsys):
    path = _dataset(tmp_path / "raw.npz", 5, [1.5, 0.0], {})
    err = _refused(sweep_cli.main, [*TOYCAR_ARGS, "--methods", "bc-oh", "--dataset", str(path),
                                    "--out", str(tmp_path / "run")], capsys)
    assert "50.0% of its label entries lie outside toycar's action range [0, 1]" in err
    assert "--set protocol.labels=raw" in err and not (tmp_path / "run").exists()
    spec = S.SweepSpec.make("toycar", "full", ("bc-oh",), sets=["protocol.labels=raw", "recipe.batch_size=8"],
                            dataset=str(path))
    assert S.prepare(spec, S.Hooks(log=lambda m: None)).train.demos.action.max() == 1.5


def test_dagger_without_a_queryable_expert_is_refused(tmp_path, capsys):
    path = _dataset(tmp_path / "theirs.npz", 5, [1.0, 0.0], {})   # names no expert
    err = _refused(sweep_cli.main, [*TOYCAR_ARGS, "--methods", "bc-oh,dagger", "--dataset", str(path),
                                    "--out", str(tmp_path / "run")], capsys)
    assert "dagger queries the expert of the demonstrations" in err and "names no expert" in err
    assert not (tmp_path / "run").exists()


@pytest.fixture(scope="module")
def hopper_pos():
    return envs.make("hopper", obs="pos")


def _hopper_spec(path, sets=()):
    return S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol="brax", recipe="mlp",
                            sets=["recipe.batch_size=8", *sets], dataset=str(path))


def test_a_dataset_normalises_by_its_own_references_else_its_experts_else_none(tmp_path, hopper_pos):
    brax = {"env_overrides": {}}
    own = collect.expert_for(envs.make("hopper", obs="full"))[1]
    logs = []
    hooks = S.Hooks(log=logs.append)
    # recorded references come first
    recorded = {"return_mean": 500.0, "return_std": 5.0, "random_return_mean": 50.0}
    path = _dataset(tmp_path / "a.npz", 5, [0.1, 0.2, 0.3], {"settings": {**brax, "expert": own},
                                                              "references": recorded})
    prepared = S.prepare(_hopper_spec(path), hooks)
    assert prepared.card == recorded and prepared.expert is not None
    assert prepared.expert_description == own
    # none recorded: its expert's under the protocol (the shipped Hopper's card, for brax)
    path = _dataset(tmp_path / "b.npz", 5, [0.1, 0.2, 0.3], {"settings": {**brax, "expert": own}})
    assert S.prepare(_hopper_spec(path), hooks).card["return_mean"] == experts.card("hopper")["return_mean"]
    # names no expert and records no references: no normalised scores, one line saying how to add them
    path = _dataset(tmp_path / "c.npz", 5, [0.1, 0.2, 0.3], {})
    prepared = S.prepare(_hopper_spec(path), hooks)
    assert prepared.card is None and prepared.expert is None
    assert any(m.startswith("no normalised scores") and '"references"' in m and "c.json" in m for m in logs)
    # an expert it does not name: the dataset's own wins only when the protocol agrees
    ppo = {**own, "path": "envs/experts/hopper-ppo"}
    path = _dataset(tmp_path / "d.npz", 5, [0.1, 0.2, 0.3], {"settings": {**brax, "expert": ppo}})
    with pytest.raises(ValueError, match="collected by expert 'ppo'.*--set protocol.expert=ppo"):
        S.prepare(_hopper_spec(path), hooks)
    # a changed card: its expert is not the one that collected it any more
    ppo_spec = _hopper_spec(path, ["protocol.expert=ppo"])
    found = collect.dataset_expert(hopper_pos, ppo_spec.task, ppo_spec.protocol, {"settings": {**brax, "expert": ppo}},
                                   "d.npz")
    assert found.expert is None and "not the one that collected it" in found.why


def test_a_minari_datasets_reference_scores_are_its_references(tmp_path):
    path = _dataset(tmp_path / "a.npz", 5, [1.0, 0.0], {})
    demos, _ = data.load(path)
    target = minari_io.to_minari(demos, {"x": 1}, "toy-v0", root=tmp_path / "m", ref_min_score=2.0,
                                 ref_max_score=40.0)
    meta = minari_io.dataset_metadata(target)
    assert meta["x"] == 1 and meta["references"]["return_mean"] == 40.0
    assert meta["references"]["random_return_mean"] == 2.0
