"""A sweep's setup, resolved once (`ape_jax.pipeline.setup`): resolving it and a sweep's fingerprint build no Brax
environment and restore no checkpoint; its data key is the one collection names datasets by; the expert's policy
is restored once per sweep, however many phases ask for it."""

import numpy as np
import pytest

import envs
from ape_jax.pipeline import collect, data as data_lib, sweep as S
from ape_jax.pipeline.setup import ExpertRef, Setup
from envs import experts


FULL = 11  # Hopper's full observation (the expert's input)


def _forbid_building(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("resolving a setup built an environment or restored a checkpoint")

    monkeypatch.setattr(envs.brax_env, "_build_brax", refuse)
    monkeypatch.setattr(experts, "load", refuse)
    monkeypatch.setattr(experts, "load_params", refuse)


def test_a_fingerprint_is_pure_data(monkeypatch):
    _forbid_building(monkeypatch)
    for env in ("hopper", "walker2d", "halfcheetah"):
        spec = S.SweepSpec.make(env, "pos", ("bc-so", "bc-oh"))
        expert = spec.fingerprint()["data"]["expert"]
        assert (expert["kind"], expert["path"]) == ("checkpoint", f"envs/experts/{env}")
    brax = S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol="brax")
    assert brax.protocol_settings()["episode_length"] == 1000 and brax.fingerprint()["data"]["episodes"] > 0
    rough = S.SweepSpec.make("hopper", "pos", ("bc-oh",), sets=["protocol.expert=rough", "protocol.labels=raw"])
    key = rough.fingerprint()["data"]
    assert key["expert"]["path"] == "envs/experts/hopper-rough" and key["labels"] == "raw"
    assert rough.setup.expert.variant == "rough" and rough.setup is rough.setup   # resolved once


@pytest.mark.parametrize("env, obs, sets", [("hopper", "pos", []), ("hopper", "pos", ["protocol.expert=ppo"]),
                                            ("toycar", "image", ["protocol.image_size=8,8"])])
def test_the_data_key_is_the_one_collection_names_datasets_by(env, obs, sets):
    spec = S.SweepSpec.make(env, obs, ("bc-oh",), sets=sets)
    by_collection = collect.data_key(env, obs, spec.episodes, expert=spec.protocol.expert,
                                     labels=spec.protocol.labels, **spec.collection_overrides())
    assert spec.data_settings() == by_collection
    assert ExpertRef.of_key(by_collection).description == spec.setup.expert.description


def test_the_known_frame_skips_are_braxs():
    for name, skip in envs.brax_env.KNOWN_FRAME_SKIPS.items():
        assert envs.brax_env._build_brax.__wrapped__(name, "mjx", ())._n_frames == skip


def test_the_expert_is_restored_once_per_sweep(monkeypatch, tmp_path):
    """The fingerprint, the collection and prepare's labeller each used to load the checkpoint again."""
    loads = []
    real = experts.load
    monkeypatch.setattr(experts, "load", lambda name, *a, **k: loads.append(name) or real(name, *a, **k))

    def collect_stub(env, expert, key, num_episodes, *args, **kwargs):   # two short episodes, acted by the expert
        n, length = 2, 60
        obs = np.zeros((n * length, *env.observation_shape), np.float32)
        action = np.asarray(expert(np.zeros((n * length, FULL), np.float32)))
        return data_lib.Demonstrations(obs=obs, action=action, executed=np.clip(action, -1, 1),
                                       episode=np.repeat(np.arange(n), length).astype(np.int32),
                                       t=np.tile(np.arange(length), n).astype(np.int32),
                                       done=np.zeros(n * length, np.float32), reward=np.ones(n * length, np.float32))

    monkeypatch.setattr(collect, "collect", collect_stub)
    spec = S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol="brax", recipe="mlp",
                            sets=["protocol.episodes=2", "recipe.batch_size=8"], data_dir=tmp_path)
    spec.fingerprint()
    prepared = S.prepare(spec, S.Hooks(log=lambda m: None))
    prepared.expert(np.zeros((1, FULL), np.float32))
    assert loads == ["hopper"] and spec.setup.references() is spec.setup.references()   # read once, kept
    again = S.SweepSpec.make("hopper", "pos", ("bc-oh",), protocol="brax", recipe="mlp",
                             sets=["protocol.episodes=2", "recipe.batch_size=8"], data_dir=tmp_path)
    S.prepare(again, S.Hooks(log=lambda m: None))   # cached demonstrations: the labeller's load only
    assert loads == ["hopper", "hopper"] and isinstance(Setup.resolve("hopper", "pos", again.protocol), Setup)


def test_a_protocol_joins_a_family_by_being_listed_there_never_by_its_name():
    from ape_jax import tasks
    from ape_jax.pipeline.presets import default_recipe
    from experiments.report.analysis import in_state_family

    assert {name: p.family for name, p in tasks.PROTOCOLS.items()} == {
        "mujoco-state": "mujoco-state", "mujoco-state-fs2": "mujoco-state", "mujoco-state-fs4": "mujoco-state",
        "mujoco-state-train5k": "mujoco-state", "mujoco-state-train80k": "mujoco-state",
        "brax": "brax", "palr-h2": "palr", "palr-h4": "palr", "nocrash": "nocrash", "nocrash-nospeed": "nocrash"}
    stranger = tasks.Protocol("fca-mine")          # named like the family, listed nowhere: a family of its own
    assert stranger.family == "fca-mine" and not in_state_family("fca-mine") and in_state_family("mujoco-state-train5k")
    assert default_recipe(stranger, "pos") == "mlp"
    assert default_recipe(tasks.PROTOCOLS["mujoco-state-fs2"], "pos") == "bn-mlp"
    assert default_recipe(tasks.PROTOCOLS["palr-h4"], "pos") == "mlp-b1024"
