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
    ctx = methods.GridContext(task=None, step_grid=(), softmax_grid=(), n_train=10, knobs=s.knobs)
    assert methods.get("scaled-oh").settings(ctx) == [{"scale": 0.5}, {"scale": 2.0}]
    default = methods.GridContext(task=None, step_grid=(), softmax_grid=(), n_train=10)
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
def test_the_sweep_trains_a_plugin_s_grid_from_its_knobs_and_refuses_knobs_of_an_idle_method(plugin, tmp_path):
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
    idle = tmp_path / "idle"
    proc = subprocess.run([sys.executable, "-m", "experiments.sweep", *common, "--methods", "bc-oh",
                           "--set", "scaled-oh.rounds=2", "--out", str(idle)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2 and "scaled-oh is not among the methods" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and not idle.exists()


def test_a_spec_rebuilt_to_evaluate_recorded_results_keeps_their_knobs(plugin):
    from ape_jax.pipeline.spec import SweepSpec

    s = resolve("hopper", "pos", preset="quick", sets=["scaled-oh.rounds=2"])
    assert SweepSpec("hopper", "pos", s, ()).settings.knobs["scaled-oh"].rounds == 2   # no methods: evaluates only
    with pytest.raises(ValueError, match="scaled-oh is not among the methods"):
        SweepSpec("hopper", "pos", s, ("bc-oh",))
