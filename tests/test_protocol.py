"""Protocols: the paper's `fca` setting (frame skip 1, 500 standard steps, rewards on the standard scale,
20,000 + 4,000 transitions) beside Brax's own, recorded, refused where they do not fit."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import tasks
from ape_jax.pipeline import collect as collect_lib
from ape_jax.pipeline import sweep as S
from ape_jax.pipeline.checkpoint import CheckpointError, SweepCheckpoint
from ape_jax.pipeline.data import Demonstrations
from envs import experts
from experiments import sweep


def test_the_mujoco_state_protocol_resolves_per_task_from_brax_frame_skips():
    hopper = S.SweepSpec.make("hopper", "pos", ("bc-oh",))
    p = hopper.protocol_settings()
    assert hopper.protocol.name == "mujoco-state" and p["split"] == "rows" and \
        (p["frame_skip"], p["standard_frame_skip"]) == (1, 4)
    assert (p["episode_length"], p["reward_scale"], p["train_transitions"], p["val_transitions"]) == \
        (2000, 0.25, 20_000, 4_000)
    assert hopper.episodes == 25   # 50,000 expert steps
    cheetah = S.SweepSpec.make("halfcheetah", "pos", ("bc-oh",))
    assert cheetah.protocol_settings()["episode_length"] == 2500 and cheetah.episodes == 20
    assert cheetah.protocol_settings()["reward_scale"] == pytest.approx(0.2)
    image = S.SweepSpec.make("hopper", "image", ("bc-oh",))
    assert image.protocol.name == "brax" and image.protocol_settings()["frame_skip"] == 4   # images keep Brax's
    assert image.recipe.name == "mlp" and hopper.recipe.name == "bn-mlp"   # the mujoco-state protocols' default recipe
    brax = S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol="brax")
    assert brax.recipe.name == "mlp" and brax.protocol.split == "episodes"
    assert brax.collection_overrides() == {} and brax.protocol_settings()["episode_length"] == 1000


def test_rewards_at_frame_skip_1_are_on_the_standard_steps_scale():
    """The same simulated time at frame skip 1 (scaled by 1/4) and 4 earns the same return: the physics
    substeps are the same, so healthy rewards and forward progress add up alike."""
    fs1 = envs.make("hopper", obs="full", n_frames=1, reward_scale=0.25, terminate_when_unhealthy=False)
    fs4 = envs.make("hopper", obs="full", terminate_when_unhealthy=False)
    assert (fs1.frame_skip, fs4.frame_skip) == (1, 4) and fs1.dt == pytest.approx(fs4.dt / 4)

    def ret(env, steps):
        def body(state, _):
            state = env.step(state, jnp.full((env.action_size,), 0.3))
            return state, state.reward
        _, rewards = jax.lax.scan(body, env.reset(jax.random.PRNGKey(3)), None, length=steps)
        return rewards.sum()

    r1, r4 = jax.jit(lambda: ret(fs1, 48))(), jax.jit(lambda: ret(fs4, 12))()
    assert float(r4) > 1.0   # it earned something to compare
    np.testing.assert_allclose(float(r1), float(r4), rtol=1e-3)   # unscaled, frame skip 1 would earn 4x


def _demos(lengths):
    t = np.concatenate([np.arange(n) for n in lengths]).astype(np.int32)
    episode = np.concatenate([np.full(n, i) for i, n in enumerate(lengths)]).astype(np.int32)
    n = len(t)
    return Demonstrations(obs=np.arange(n, dtype=np.float32)[:, None], action=np.zeros((n, 1), np.float32),
                          executed=np.zeros((n, 1), np.float32), episode=episode, t=t,
                          done=np.zeros(n, np.float32), reward=np.zeros(n, np.float32), sim={})


def test_split_sizes_gives_exact_sizes_from_disjoint_episodes():
    demos = _demos([100] * 25)
    train, val = demos.split_sizes(400, 80, seed=0)
    assert (len(train), len(val)) == (400, 80)
    assert not set(np.asarray(train.episode)) & set(np.asarray(val.episode))
    for split in (train, val):   # every episode starts at t = 0 and runs on without gaps
        ep, t = np.asarray(split.episode), np.asarray(split.t)
        starts = np.flatnonzero(np.r_[True, ep[1:] != ep[:-1]])
        assert np.all(t[starts] == 0) and np.all(np.diff(t)[np.diff(ep) == 0] == 1)
    with pytest.raises(ValueError, match="fewer than the 2,000 \\+ 600 the split needs"):
        demos.split_sizes(2_000, 600)


def test_an_unknown_protocol_or_one_the_task_cannot_take_is_refused(capsys):
    for argv, message in ((["--protocol", "gym"], "unknown protocol 'gym' for hopper; valid: mujoco-state, "
                                                  "mujoco-state-fs2, mujoco-state-fs4, mujoco-state-train5k, "
                                                  "mujoco-state-train80k, brax"),
                          (["--env", "toycar", "--protocol", "fca"],   # a former name, refused by its new one
                           "unknown protocol 'mujoco-state' for toycar; valid: brax")):
        with pytest.raises(SystemExit) as exc:
            sweep.parse(argv)
        assert exc.value.code == 2 and message in capsys.readouterr().err


def test_a_dataset_of_another_protocol_is_refused(tmp_path, capsys):
    (tmp_path / "old.json").write_text(json.dumps({"settings": {"env_overrides": {}}}))   # Brax's defaults
    (tmp_path / "old.npz").write_bytes(b"")
    with pytest.raises(SystemExit) as exc:
        sweep.main(["--dataset", str(tmp_path / "old.npz"), "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "not under the 'mujoco-state' protocol's" in err and "--protocol" in err
    assert not (tmp_path / "run").exists()


def test_a_checkpoint_of_another_protocol_is_not_resumed(tmp_path):
    fca = S.SweepSpec.make("hopper", "pos", ("bc-oh",))
    brax = S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol="brax", recipe="bn-mlp")
    SweepCheckpoint(tmp_path / "ck", fca.fingerprint(), 100).open()
    with pytest.raises(CheckpointError, match="protocol"):
        SweepCheckpoint(tmp_path / "ck", brax.fingerprint(), 100).open()


def test_expert_references_come_per_protocol(tmp_path):
    card = experts.card("hopper")
    assert experts.reference("hopper", "brax")["return_mean"] == card["return_mean"]
    root = tmp_path / "hopper"
    root.mkdir()
    (root / experts.CARD).write_text(json.dumps(card))
    with pytest.raises(experts.ExpertError, match="experiments.expert_references --env hopper --protocol mujoco-state"):
        experts.reference("hopper", "mujoco-state", root=root)
    (root / experts.REFERENCES).write_text(json.dumps({"mujoco-state": {"return_mean": 1.0, "return_std": 0.5,
                                                               "random_return_mean": 0.1, "episodes": 100}}))
    assert experts.reference("hopper", "mujoco-state", root=root) == {"return_mean": 1.0, "return_std": 0.5,
                                                             "random_return_mean": 0.1, "episodes": 100}
    assert tasks.PROTOCOLS["mujoco-state"].settings(4)["episode_length"] == 2000


@pytest.mark.parametrize("name,standard,length,scale", [
    ("mujoco-state", 4, 2000, 0.25), ("mujoco-state-fs2", 4, 1000, 0.5), ("mujoco-state-fs4", 4, 500, 1.0),
    ("mujoco-state-fs4", 5, 625, 0.8)])
def test_the_copycat_maps_protocols_keep_fcas_time_rewards_and_data_at_every_frame_skip(name, standard, length, scale):
    """The map's columns differ only in frame skip: 500 standard steps of simulated time, returns on the standard
    scale, the same 50,000 expert steps and 20,000 / 4,000 training / validation transitions."""
    s = tasks.PROTOCOLS[name].settings(standard)
    assert (s["episode_length"], s["reward_scale"]) == (length, scale)
    assert s["episode_length"] * s["frame_skip"] == 500 * standard                    # the same simulated time
    assert (s["collect_transitions"], s["train_transitions"], s["val_transitions"]) == (50_000, 20_000, 4_000)
    assert name in tasks.get("hopper").protocols and name not in tasks.get("toycar").protocols


@pytest.mark.parametrize("protocol", [None, "mujoco-state-fs2", "brax"])
def test_collect_names_the_dataset_the_sweep_of_the_same_protocol_uses(protocol, tmp_path):
    """`experiments.collect` defaults to the sweep's protocol, so what it collects is what `--dataset` accepts."""
    from experiments import collect as collect_cli

    flags = [] if protocol is None else ["--protocol", protocol]
    args = collect_cli.parse(["--env", "hopper", "--obs", "pos", "--data-dir", str(tmp_path), *flags])
    spec = S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol=protocol)
    assert args.setup.name == spec.protocol.name == (protocol or "mujoco-state")
    assert args.episodes == spec.episodes
    mine = collect_lib.data_key("hopper", "pos", args.episodes, seed=args.seed, **args.overrides)
    assert mine == spec.data_settings()   # the same settings: the same cached file


def test_collect_refuses_a_protocol_the_task_cannot_take(capsys):
    from experiments import collect as collect_cli

    for argv, message in ((["--env", "hopper", "--protocol", "gym"], "unknown protocol 'gym' for hopper"),
                          (["--env", "toycar", "--protocol", "mujoco-state"],
                           "unknown protocol 'mujoco-state' for toycar; valid: brax")):
        with pytest.raises(SystemExit) as exc:
            collect_cli.parse(argv)
        assert exc.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("name,train,collected", [("mujoco-state-train5k", 5_000, 50_000),
                                                   ("mujoco-state-train80k", 80_000, 90_000)])
def test_the_maps_data_size_protocols_change_only_the_training_transitions(name, train, collected):
    """mujoco-state with another training-set size: the simulator settings (and so the expert references) are its."""
    p, fca = tasks.PROTOCOLS[name], tasks.PROTOCOLS["mujoco-state"]
    assert (p.train_transitions, p.collect_transitions, p.val_transitions) == (train, collected, 4_000)
    assert p.env_overrides(4) == fca.env_overrides(4) and p.reference == "mujoco-state"
    s, f = p.settings(4), fca.settings(4)
    assert {k: v for k, v in s.items() if k not in ("name", "train_transitions", "collect_transitions")} == \
        {k: v for k, v in f.items() if k not in ("name", "train_transitions", "collect_transitions")}
    spec = S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol=name)
    assert spec.episodes == collected // 2000
