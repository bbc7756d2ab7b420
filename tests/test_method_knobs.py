"""A method's own settings (`Method.knobs`): declared in its module, set as `--set METHOD.KNOB=VALUE`, recorded in
results.json, read back, replayed, and refused in one line where they cannot be."""

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import pytest

from ape_jax import methods
from ape_jax.pipeline import method_knobs
from ape_jax.pipeline.presets import Settings, SettingsError, resolve
from ape_jax.pipeline.replay import arguments

PLUGIN = '''
    import dataclasses

    from ape_jax import methods
    from ape_jax.learner import Hparams


    @dataclasses.dataclass(frozen=True)
    class ScaledKnobs:
        scales: tuple[float, ...] = (1.0,)   # a grid axis: the learning rate × each
        rounds: int = 1                      # a static setting

        def __post_init__(self):
            if not all(s > 0 for s in self.scales) or self.rounds < 1:
                raise ValueError(f"scaled-oh: scales must be > 0 and rounds >= 1, got {self.scales} and {self.rounds}")


    methods.register(methods.Method(
        "scaled-oh", "BC-OH, scaled lr", knobs=ScaledKnobs, role="plugin", module=__name__,
        grid=lambda ctx: [{"scale": s} for s in ctx.knobs_of("scaled-oh").scales],
        hparams=lambda settings, lr, row: Hparams.make("uniform", lr=lr * settings["scale"])))
'''


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    d = tmp_path / "plugins"
    d.mkdir()
    (d / "scaled_oh.py").write_text(textwrap.dedent(PLUGIN))
    monkeypatch.syspath_prepend(str(d))
    with methods.scratch():
        methods.load_plugins(["scaled_oh"])
        yield d
    sys.modules.pop("scaled_oh", None)


def test_a_method_s_knobs_are_set_recorded_read_back_and_replayed(plugin):
    s = resolve("hopper", "pos", preset="quick", sets=["scaled-oh.scales=0.5,2", "scaled-oh.rounds=3"])
    record = s.knobs["scaled-oh"]
    assert (record.scales, record.rounds) == ((0.5, 2.0), 3)
    blocks = s.to_json()
    assert blocks["knobs"] == {"scaled-oh": {"scales": [0.5, 2.0], "rounds": 3}}
    assert Settings.from_json(json.loads(json.dumps(blocks)), preset="quick").knobs == s.knobs
    assert "knobs" not in resolve("hopper", "pos", preset="quick").to_json()   # earlier files' settings unchanged
    args = arguments("hopper", "pos", s)
    assert "scaled-oh.scales=0.5,2" in args and "scaled-oh.rounds=3" in args
    ctx = methods.GridContext(task=None, n_train=10, knobs=s.knobs)
    assert methods.get("scaled-oh").settings(ctx) == [{"scale": 0.5}, {"scale": 2.0}]
    default = methods.GridContext(task=None, n_train=10)
    assert methods.get("scaled-oh").settings(default) == [{"scale": 1.0}]
    smoke = resolve("hopper", "pos", preset="quick", sets=["scaled-oh.scales=0.5,2"], smoke=True)
    assert smoke.knobs["scaled-oh"].scales == (0.5,)


@pytest.mark.parametrize("item, needle", [
    ("scaled-oh.scales=-1", "scaled-oh: scales must be > 0"),
    ("scaled-oh.speed=2", "scaled-oh has no setting 'speed'; valid: scaled-oh.scales, scaled-oh.rounds"),
    ("scaled-oh.rounds=two", "scaled-oh.rounds takes"),
    ("bc-oh.scales=1", "unknown section 'bc-oh'"),
])
def test_bad_knobs_are_refused_in_one_line(plugin, item, needle):
    with pytest.raises(SettingsError) as e:
        resolve("hopper", "pos", preset="quick", sets=[item])
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_a_record_must_be_a_frozen_dataclass():
    @dataclasses.dataclass
    class Loose:
        x: int = 1

    with methods.scratch(), pytest.raises(methods.MethodError, match="frozen dataclass"):
        methods.register(methods.Method("loose", "Loose", grid=lambda ctx: [{}], hparams=lambda s, lr, r: None,
                                        knobs=Loose))


def test_knobs_of_a_method_without_any_are_refused():
    with pytest.raises(methods.MethodError, match="no settings of its own"):
        methods.knobs_of("bc-oh", {})
    assert method_knobs.owns("bc-oh") is False and method_knobs.owns("no-such-method") is False


@pytest.mark.integration
def test_the_sweep_trains_a_plugin_s_grid_from_its_knobs(plugin, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(plugin)}
    out = tmp_path / "run"
    common = ["--plugins", "scaled_oh", "--env", "toycar", "--obs", "full", "--iterations", "10",
              "--eval-episodes", "1", "--quiet", "--set", "budget.probe_steps=0", "--data-dir", str(tmp_path / "data")]
    proc = subprocess.run([sys.executable, "-m", "experiments.sweep", *common, "--methods", "bc-oh,scaled-oh",
                           "--set", "scaled-oh.scales=0.5,2", "--out", str(out)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = json.loads((out / "results.json").read_text())
    assert [(x["method"], x["hparams"]) for x in r["runs"]] == [
        ("bc-oh", {}), ("scaled-oh", {"scale": 0.5}), ("scaled-oh", {"scale": 2.0})]
    assert r["settings"]["knobs"] == {"scaled-oh": {"scales": [0.5, 2.0], "rounds": 1}}


def test_a_setting_of_a_method_not_run_is_refused_naming_the_method(plugin, capsys):
    from experiments import sweep

    with pytest.raises(SystemExit) as exc:
        sweep.parse(["--plugins", "scaled_oh", "--methods", "bc-oh", "--set", "scaled-oh.rounds=2"], writes=False)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1, err
    assert "--set scaled-oh.rounds=2: scaled-oh is not among --methods (bc-oh)" in err and "add scaled-oh" in err


def test_a_spec_keeps_the_knobs_of_methods_it_does_not_train(plugin):
    """A spec rebuilt to evaluate recorded results (no methods), and one whose preset sets the grids of methods it
    leaves out (the image presets' step and softmax grids), keep those settings: only the command line refuses a
    method's setting given for a method not run (above)."""
    from ape_jax.pipeline.spec import SweepSpec

    s = resolve("hopper", "pos", preset="quick", sets=["scaled-oh.rounds=2"])
    assert SweepSpec("hopper", "pos", s, ()).settings.knobs["scaled-oh"].rounds == 2   # no methods: evaluates only
    assert SweepSpec("hopper", "pos", s, ("bc-oh",)).settings.knobs["scaled-oh"].rounds == 2
    images = resolve("hopper", "image", preset="quick")
    assert images.knob("ours-softmax").taus == () and images.knob("ours-step").grid == ((0.1, 5.0),)
    assert SweepSpec("hopper", "image", images, ("bc-oh",)).settings.knobs == images.knobs


def test_no_method_knob_is_left_in_the_recipe_and_each_old_name_maps_to_a_method_s_own():
    from ape_jax.pipeline.presets import Recipe

    recipe = {f.name for f in dataclasses.fields(Recipe)}
    assert not recipe & set(method_knobs.LEGACY)
    for owners, knob, _ in method_knobs.LEGACY.values():
        targets = methods.sharing(owners) if isinstance(owners, type) else list(owners)
        assert targets and all(knob in {f.name for f in dataclasses.fields(methods.get(m).knobs)} for m in targets)


def test_an_old_recipe_name_sets_the_knob_it_is_now_with_a_notice(capsys):
    method_knobs._noticed.clear()
    old = resolve("hopper", "pos", sets=["recipe.fca_alphas=0.1,2", "recipe.palr_rows=64", "recipe.rap_widths="])
    assert "notice: recipe.fca_alphas is now fca.alphas, fca-ib.alphas" in capsys.readouterr().err
    new = resolve("hopper", "pos", sets=["fca.alphas=0.1,2", "fca-ib.alphas=0.1,2", "palr.rows=64"])
    assert old == new and old.knob("rap").widths == (150,)   # an empty old grid meant the method's default


def test_a_file_recording_the_old_recipe_fields_reads_as_the_records_they_mean():
    """A results file or checkpoint from before the methods owned their settings: its recipe's method fields become
    the methods' records, so its settings (and fingerprint, `checkpoint.differences`) equal today's for the same
    command."""
    from ape_jax.pipeline.checkpoint import differences

    today = resolve("hopper", "pos", preset="default", sets=["ours-step.grid=0.1:5", "fca.alphas=0.1",
                                                               "fca-ib.alphas=0.1", "mine.steps=5"])
    blocks = today.to_json()
    del blocks["knobs"]
    old = {**blocks, "recipe": {**blocks["recipe"], "step_grid": [[0.1, 5.0]],
                                "softmax_grid": [0.1, 0.2, 0.5, 1.0, 5.0, 10.0], "fca_alphas": [0.1],
                                "fca_adversary_lr": None, "ib_weights": [], "rap_weights": [], "rap_widths": [],
                                "palr_weights": [], "palr_bandwidths": [], "palr_rows": 256, "mine_weights": [],
                                "mine_steps": 5, "mine_rows": 256}}
    assert "knobs" not in old
    assert Settings.from_json(old, preset="default") == dataclasses.replace(today, preset_iterations=None)
    assert differences({"settings": old}, {"settings": today.to_json()}) == []
    assert differences({"settings": old}, {"settings": resolve("hopper", "pos", preset="default").to_json()})
