"""The perception stage (`ape_jax.perception`): the encoder file and its card, the refusals, the environment that
observes embeddings, the pretraining's targets, and encoders kept apart in results and reports."""

from __future__ import annotations

import dataclasses
import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import observations, tasks
from ape_jax import perception
from ape_jax.perception import card as card_lib
from ape_jax.pipeline import perception as pretrain_lib
from ape_jax.perception.net import PerceptionNet, net_spec
from ape_jax.pipeline import presets
from ape_jax.pipeline.presets import SettingsError
from tests.test_cli_guards import refused

ROOT = pathlib.Path(__file__).resolve().parents[1]


def tiny_encoder(path: pathlib.Path, task: str = "toytown", image_size=(64, 64), task_version=2, palette="train",
                 targets=("speed", "lane_offset"), seed: int = 0) -> str:
    """A user's own encoder in the documented format: a tiny network, random weights; returns its SHA-256."""
    net = PerceptionNet(targets=len(targets), patches=(8,), channels=(4,), hidden=8, embedding=6)
    params = net.init(jax.random.PRNGKey(seed), np.zeros((1, *image_size, 3), np.uint8))
    card = {"task": task, "targets": list(targets), "target_obs": "pos", "image_size": list(image_size),
            "task_version": task_version, "palette": palette, "net": net_spec(net),
            "target_mean": [0.0] * len(targets), "target_std": [1.0] * len(targets)}
    return card_lib.save(path, params, card)


@pytest.fixture
def encoder_file(tmp_path):
    path = tmp_path / "mine.npz"
    return path, tiny_encoder(path)


# -- the file --------------------------------------------------------------------------------------------------------

def test_an_encoder_file_reads_back_with_its_card_parameters_and_sha256(encoder_file):
    path, sha = encoder_file
    enc = card_lib.load(path)
    assert enc.sha256 == sha == card_lib.file_sha256(path)
    assert enc.embedding_size == 6 and enc.card["targets"] == ["speed", "lane_offset"]
    frames = np.random.default_rng(0).integers(0, 256, (3, 64, 64, 3), np.uint8)
    e = perception.embed_frames(enc, frames)
    assert e.shape == (3, 6) and e.dtype == np.float32 and np.isfinite(e).all()
    assert not np.allclose(e[0], e[1])   # it reads the frame
    assert enc.describe()["sha256"] == sha and enc.describe()["targets"] == ["speed", "lane_offset"]


@pytest.mark.parametrize("damage, words", [
    ("missing", "no such encoder file"),
    ("truncated", "not a readable encoder file"),
    ("garbage", "not a readable encoder file"),
    ("format", "this code reads format 1"),
    ("shapes", "do not fit the network its card describes"),
])
def test_a_damaged_encoder_file_is_refused_in_one_line(tmp_path, encoder_file, damage, words):
    path, _ = encoder_file
    bad = tmp_path / "bad.npz"
    if damage == "truncated":
        bad.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "garbage":
        bad.write_bytes(b"not an archive")
    elif damage in ("format", "shapes"):
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        card = json.loads(str(arrays["card.json"][()]))
        if damage == "format":
            card["format"] = 9
        else:
            card["net"]["hidden"] = 16
        arrays["card.json"] = np.array(json.dumps(card))
        np.savez(bad, **arrays)
        bad = bad.with_suffix(".npz")
    with pytest.raises(card_lib.PerceptionError, match=words) as e:
        card_lib.load(bad)
    assert "\n" not in str(e.value)


def test_an_encoder_made_for_another_task_size_version_or_palette_is_refused(tmp_path):
    cases = {"task": dict(task="toycar"), "size": dict(image_size=(32, 32)), "version": dict(task_version=1),
             "palette": dict(palette="test")}
    for name, kw in cases.items():
        path = tmp_path / f"{name}.npz"
        tiny_encoder(path, **kw)
        with pytest.raises(card_lib.PerceptionError) as e:
            card_lib.check_fits(card_lib.load(path), "toytown", (64, 64), 2, "train")
        assert {"task": "toycar's frames", "size": "32×32", "version": "task version 1",
                "palette": "'test' palette"}[name] in str(e.value)


# -- the settings ----------------------------------------------------------------------------------------------------

def test_a_sweep_through_an_encoder_records_its_sha256_and_trains_state_policies(encoder_file):
    path, sha = encoder_file
    s = presets.resolve("toytown", "image", preset="default", sets=[f"recipe.perception={path}"])
    assert s.recipe.perception_sha256 == sha
    assert (s.recipe.encoder, s.recipe.encoder_norm, s.recipe.augment_shift) == ("small", "none", 0)
    cfg = s.learner_config((6,), 3, 2, "l1")
    assert not cfg.images and cfg.obs_shape == (6,)
    pinned = presets.resolve("toytown", "image", sets=[f"recipe.perception={path}", f"recipe.perception_sha256={sha}"])
    assert pinned.recipe.perception_sha256 == sha


@pytest.mark.parametrize("sets, obs, env, words", [
    (["recipe.perception=task"], "image", "toycar", "toycar declares no perception card"),
    (["recipe.perception=task"], "pos", "toytown", "recipe.perception reads camera frames"),
    (["recipe.perception={path}", "recipe.encoder=patch"], "image", "toytown", "recipe.encoder: for policies that "
     "learn from pixels"),
    (["recipe.perception={path}", "recipe.perception_sha256=" + "0" * 64], "image", "toytown",
     "is not the 000000000000"),
    (["recipe.perception={path}", "recipe.perception_sha256=abc"], "image", "toytown", "64 hexadecimal digits"),
    (["recipe.perception={path}", "protocol.image_size=32"], "image", "toytown", "not the sweep's 32×32"),
    (["recipe.perception={path}", "protocol.task_version=1"], "image", "toytown", "not the sweep's 1"),
    (["recipe.perception=/nowhere/enc.npz"], "image", "toytown", "no such encoder file"),
])
def test_perception_settings_that_cannot_run_are_refused(encoder_file, sets, obs, env, words):
    path, _ = encoder_file
    with pytest.raises(SettingsError, match=words.replace("(", r"\(")) as e:
        presets.resolve(env, obs, sets=[item.format(path=path) for item in sets])
    assert "\n" not in str(e.value)


def test_every_table_method_can_run_through_an_encoder(encoder_file):
    from ape_jax.pipeline.spec import SweepSpec

    path, _ = encoder_file
    methods = ("bc-so", "bc-oh", "ours-step", "fca", "history-dropout", "dagger", "boosting", "rap", "palr", "mine",
               "bc-full")
    spec = SweepSpec.make("toytown", "image", methods=methods, preset="default", sets=[f"recipe.perception={path}"])
    assert spec.policy_obs == "embedding" and spec.methods == methods


def test_the_sweep_command_refuses_a_missing_encoder_in_one_line_and_writes_nothing(tmp_path, capsys):
    from experiments import sweep

    out = tmp_path / "run"
    err = refused(capsys, lambda: sweep.main(["--env", "toytown", "--set", f"recipe.perception={tmp_path}/no.npz",
                                              "--yes", "--out", str(out)]))
    assert "no such encoder file" in err and not out.exists()


# -- the environment -------------------------------------------------------------------------------------------------

def test_the_perceived_environment_observes_the_frames_embedding(encoder_file):
    path, _ = encoder_file
    enc = card_lib.load(path)
    camera = envs.make("toytown", obs="image", route_length=180.0, intersections=2, episode_length=50)
    env = perception.Perceived(camera, enc)
    assert env.observation_shape == (6,)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    frame = camera.render(state)
    np.testing.assert_allclose(state.obs, perception.embed_frames(enc, np.asarray(frame)[None])[0], rtol=1e-5,
                               atol=1e-6)
    step = jax.jit(env.step)
    for _ in range(3):
        state = step(state, jnp.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(state.obs, perception.embed_frames(enc, np.asarray(camera.render(state))[None])[0],
                               rtol=1e-5, atol=1e-6)
    assert float(state.pipeline_state.v) > 0   # the car drives: the inner environment stepped
    assert observations.full_env(env).obs_mode == "full"   # bc-full reads the camera's task's full state


# -- pretraining -----------------------------------------------------------------------------------------------------

@pytest.mark.integration   # four collections, each its own compile: ~20-40 s on 2 cores
def test_pretraining_reads_the_one_frame_targets_and_never_the_actions(monkeypatch):
    task = tasks.get("toytown")
    small = dataclasses.replace(task.perception, episodes=3, perturbed_episodes=1, heldout_episodes=1, stride=3,
                                frame_settings={**task.perception.frame_settings, "route_length": 180.0,
                                                "intersections": 2, "episode_length": 150})
    monkeypatch.setattr(tasks, "TASKS", {**tasks.TASKS, "toytown": dataclasses.replace(task, perception=small)})
    params, card = pretrain_lib.pretrain("toytown", steps=300, batch=32, lr=3e-3)
    env = envs.make("toytown", obs="pos")
    assert card["targets"] == list(env.observation_names) and "throttle" not in card["targets"]
    assert card["target_obs"] == "pos" and card["task_version"] == 2 and card["palette"] == "train"
    assert set(card["heldout"]) == {"test layouts", "test layouts, test weather"}
    read = card["heldout"]["test layouts"]
    assert set(read) == set(card["targets"])
    assert read["speed"] < 0.5   # the strip's grey level is read off one frame


def test_tasks_without_a_card_are_refused_by_the_pretraining_command(capsys):
    from experiments import perception as cli

    err = refused(capsys, lambda: cli.main(["--env", "toycar"]))
    assert "toycar declares no perception card" in err
    err = refused(capsys, lambda: cli.main(["--env", "toytown", "--image-size", "abc"]))
    assert "--image-size 'abc': an image size is" in err


# -- results and reports ---------------------------------------------------------------------------------------------

def test_two_encoders_never_merge_in_the_report():
    from experiments.report.analysis import groups
    from ape_jax.pipeline import results as results_lib

    obj = json.loads((ROOT / "results" / "toytown-image-nocrash-default-seeds0.json").read_text())
    files = []
    for sha in ("a" * 64, "b" * 64):
        o = json.loads(json.dumps(obj))
        o["settings"]["recipe"]["perception"] = "task"
        o["settings"]["recipe"]["perception_sha256"] = sha
        files.append(results_lib.Results.from_json(o))
    merged = groups.merge(files)
    assert {k.perception for k in merged} == {"a" * 12, "b" * 12}
    titles = sorted(g.title for g in merged.values())
    assert "through the pretrained encoder aaaaaaaa" in titles[0]
    assert len({groups.file_stem(g) for g in merged.values()}) == 2


def test_the_sweeps_reference_block_names_frames_seen_through_an_encoder():
    from experiments import _reference
    from ape_jax.pipeline import results as results_lib

    obj = json.loads((ROOT / "results" / "toytown-image-nocrash-default-seeds0.json").read_text())
    plain = results_lib.Results.from_json(obj)
    seen = json.loads(json.dumps(obj))
    seen["settings"]["recipe"]["perception_sha256"] = "c" * 64
    seen["config"]["iterations"] = 300
    lines = _reference.rate_lines(results_lib.Results.from_json(seen), (plain,))
    mine = next(line for line in lines if line.endswith("<- this run"))
    assert mine.split()[0] == "image+encoder"
    assert any(line.split()[:1] == ["image"] for line in lines)   # the shipped from-scratch camera row


def test_a_near_target_is_read_back_in_its_own_units():
    from ape_jax.perception.net import far, near

    gaps = np.array([0.0, 3.0, 12.5, 40.0], np.float32)
    np.testing.assert_allclose(np.asarray(far(near(gaps, 10.0), 10.0)), gaps, atol=1e-4)
    assert near(3.0, 10.0) - near(4.0, 10.0) > 10 * (near(30.0, 10.0) - near(31.0, 10.0))   # steep up close
