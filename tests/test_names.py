"""One name per thing (`docs/design.md`, "Words"): the MuJoCo-State protocol is `mujoco-state`, the FCA code's recipe
`bn-mlp`, PALR's code's recipe `mlp-b1024`, FCA's imported expert `cs294`; "fca" and "palr" are the algorithms
only. The former names read as the new ones: on
the command line with a notice, in results files and checkpoints silently, so they keep their settings,
fingerprints and replays. And the APE's normalisation, the softmax weightings' own setting."""

import copy
import dataclasses
import json
import pathlib

import pytest

from ape_jax import methods, tasks
from ape_jax.pipeline import checkpoint, presets, renames, results
from ape_jax.pipeline.presets import SettingsError, resolve


def test_fca_names_only_the_method_in_the_cli():
    assert "fca" in methods.names()
    assert not [p for p in tasks.PROTOCOLS if "fca" in p]
    assert not [r for r in presets.RECIPES if "fca" in r]
    assert tasks.FAMILIES[tasks.STATE][0].name == "mujoco-state"
    assert resolve("hopper", "pos").protocol.name == "mujoco-state"
    assert resolve("hopper", "pos").recipe.name == "bn-mlp"
    assert all(new in tasks.PROTOCOLS for new in tasks.FORMER_PROTOCOLS.values())


def test_no_protocol_recipe_method_or_shipped_expert_shares_a_name():
    shipped = (pathlib.Path(tasks.__file__).parents[1] / "envs" / "experts").iterdir()
    experts = {d.name.partition("-")[2] for d in shipped if d.is_dir() and "-" in d.name}
    experts |= set(tasks.FORMER_EXPERTS.values())
    kinds = {"protocol": set(tasks.PROTOCOLS), "recipe": set(presets.RECIPES), "method": set(methods.names()),
             "expert": experts}
    assert experts >= {"rough", "ppo", "cs294"}
    for a in kinds:
        for b in kinds:
            assert a == b or not kinds[a] & kinds[b], (a, b, kinds[a] & kinds[b])


def test_palr_s_recipe_is_mlp_b1024_and_its_former_name_reads_as_it(capsys):
    renames._noticed.clear()
    assert resolve("halfcheetah", "pos", protocol="palr-h2").recipe.name == "mlp-b1024"
    old = resolve("halfcheetah", "pos", protocol="palr-h2", recipe="palr")
    assert "notice: recipe 'palr' is now 'mlp-b1024'" in capsys.readouterr().err
    assert old == resolve("halfcheetah", "pos", protocol="palr-h2", recipe="mlp-b1024")
    assert presets.Recipe("palr", lr=3e-4, batch_size=1024, lr_decay_at=()) == presets.RECIPES["mlp-b1024"]


def test_the_former_names_resolve_to_the_same_settings_with_one_notice_each(capsys):
    renames._noticed.clear()
    old = resolve("hopper", "pos", protocol="fca-fs2", recipe="fca", sets=["protocol.expert=fca"])
    err = capsys.readouterr().err
    assert "notice: protocol 'fca-fs2' is now 'mujoco-state-fs2'" in err
    assert "notice: recipe 'fca' is now 'bn-mlp'" in err
    assert "notice: protocol.expert 'fca' is now 'cs294'" in err and "--name cs294" in err
    new = resolve("hopper", "pos", protocol="mujoco-state-fs2", recipe="bn-mlp", sets=["protocol.expert=cs294"])
    assert old == new and tasks.Protocol("fca-train5k", reference="fca").reference == "mujoco-state"
    resolve("hopper", "pos", protocol="fca-fs2", recipe="fca")
    assert capsys.readouterr().err == ""   # once per process


def _old_names(blocks: dict) -> dict:
    """`blocks` (a results file or fingerprint) as a file from before the renaming records them."""
    old = copy.deepcopy(blocks)
    for p in (old.get("protocol"), (old.get("settings") or {}).get("protocol")):
        if isinstance(p, dict):
            p.update({k: {"mujoco-state": "fca", "mujoco-state-fs2": "fca-fs2", "cs294": "fca"}.get(v, v)
                      for k, v in p.items() if k in ("name", "reference", "expert")})
    old["settings"]["recipe"]["name"] = "fca"
    expert = (old.get("data") or {}).get("expert")
    if expert:
        expert.update(name="hopper-fca", variant="fca")
    return old


def test_a_checkpoint_started_under_the_former_names_resumes_under_the_new():
    settings = resolve("hopper", "pos", preset="paper", sets=["protocol.expert=cs294", "protocol.labels=raw"])
    data = {"env": "hopper", "expert": {"kind": "imported", "name": "hopper-cs294", "variant": "cs294",
                                        "sha256": "56" * 32}}
    new = results.fingerprint("hopper", "pos", "paper", settings.to_json(), ["bc-oh"], data,
                              {"name": "mujoco-state", "expert": "cs294", "frame_skip": 1})
    old = _old_names(new)
    assert old["protocol"]["name"] == "fca" and old["data"]["expert"]["variant"] == "fca"
    assert checkpoint.differences(old, new) == []
    other = copy.deepcopy(old)
    other["data"]["expert"]["sha256"] = "57" * 32   # another file under the old name is still another expert
    assert checkpoint.differences(other, new)


def test_a_results_file_with_the_former_names_reads_as_the_new(tmp_path):
    src = json.load(open("results/hopper-pos-fca-rows-default-fca-fcaexpert-clipped-after.json"))
    assert src["protocol"]["name"] == "fca" and src["settings"]["recipe"]["name"] == "fca"
    res = results.Results.from_json(src)
    assert (res.protocol["name"], res.protocol["expert"], res.recipe_name) == ("mujoco-state", "cs294", "bn-mlp")
    assert res.config["data"]["settings"]["expert"]["name"] == "hopper-cs294"
    assert res.records().protocol == resolve("hopper", "pos", preset="default", sets=[
        "protocol.expert=cs294"]).protocol
    assert src["protocol"]["name"] == "fca"   # the caller's object, as the file on disk, is left as written


def test_references_measured_under_the_former_name_are_found(tmp_path, monkeypatch):
    from envs import experts

    calls = []

    def reference(name, protocol="brax", root=None):
        calls.append(protocol)
        if protocol != "fca-fs2":
            raise experts.ExpertError(f"no reference under {protocol}")
        return {"return_mean": 1.0}

    monkeypatch.setattr(experts, "reference", reference)
    from ape_jax.pipeline.setup import reference_returns

    assert reference_returns("hopper", tasks.PROTOCOLS["mujoco-state-fs2"]) == {"return_mean": 1.0}
    assert calls == ["mujoco-state-fs2", "fca-fs2"]
    calls.clear()
    with pytest.raises(experts.ExpertError, match="no reference under mujoco-state$"):
        reference_returns("hopper", tasks.PROTOCOLS["mujoco-state"])


# -- the APE's normalisation: the softmax weightings' own setting --------------------------------------------------

def test_ape_normalization_is_the_softmax_weightings_knob_and_the_old_recipe_name_maps_to_it(capsys):
    assert "ape_normalization" not in {f.name for f in dataclasses.fields(presets.Recipe)}
    assert resolve("hopper", "pos").ape_normalization == "none"
    new = resolve("hopper", "pos", sets=["ours-softmax.ape_normalization=mean"])
    assert new.ape_normalization == "mean" and new.knob("ours-softmax").ape_normalization == "mean"
    old = resolve("hopper", "pos", sets=["recipe.ape_normalization=mean"])
    assert "recipe.ape_normalization is now ours-softmax.ape_normalization" in capsys.readouterr().err
    assert old == new
    blocks = resolve("hopper", "pos").to_json()
    blocks["recipe"]["ape_normalization"] = "mean"   # a file from before
    assert presets.Settings.from_json(blocks).ape_normalization == "mean"
    with pytest.raises(SettingsError, match="ape_normalization must be one of mean, none"):
        resolve("hopper", "pos", sets=["ours-softmax.ape_normalization=median"])


def test_two_softmax_weightings_that_scale_the_one_ape_differently_are_refused():
    with methods.scratch():
        ours = methods.get("ours-softmax")
        methods.register(dataclasses.replace(ours, name="my-softmax", label="my softmax", role="plugin"))
        assert resolve("hopper", "pos", sets=["ours-softmax.ape_normalization=mean",
                                              "my-softmax.ape_normalization=mean"]).ape_normalization == "mean"
        with pytest.raises(SettingsError, match="the softmax weightings' ape_normalization differ"):
            resolve("hopper", "pos", sets=["ours-softmax.ape_normalization=mean"])
