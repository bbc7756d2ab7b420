"""`experiments.report`: tables built from results files, merged per environment; bad files refused."""

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from ape_jax import tasks
from ape_jax.pipeline.presets import resolve
from ape_jax.pipeline.results import Results, summarize
from experiments.report.analysis import former_preset
from experiments import report
from experiments import stats
from experiments.report import figures


def _results(env="hopper", methods=(("bc-so", {}, 300.0), ("bc-oh", {}, 1000.0),
                                     ("ours-step", {"thr": 0.1, "w": 5.0}, 1500.0),
                                     ("ours-step", {"thr": 0.2, "w": 3.0}, 1600.0),
                                     ("ours-softmax", {"tau": 5.0}, 1200.0)), preset_methods=None,
             deltas=(-10.0, 10.0)):
    """A schema-1 results file: per method, one seed per `deltas` returning `ret + delta`, `normalized` (% of the
    expert's 2,000) `(ret + delta) / 20`; the summary their mean and std over seeds."""
    runs, summary = [], []
    std = float(np.std(deltas))
    for method, hp, ret in methods:
        for seed, delta in enumerate(deltas):
            runs.append({"method": method, "hparams": hp, "seed": seed, "status": "ok", "error": None,
                         "eval": {"episodes": 5, "return_mean": ret + delta, "return_std": 1.0,
                                  "normalized": (ret + delta) / 20},
                         "losses": {s: {"unweighted": 0.1 + seed, "changepoint": 0.3, "copycat": 0.05}
                                    for s in ("train", "val")}})
        summary.append({"method": method, "hparams": hp, "n_seeds": len(deltas), "return_mean": ret,
                        "return_std": std, "normalized_mean": ret / 20, "normalized_std": std / 20})
    return {"schema": 1, "env": env, "obs": "pos", "preset": "default",
            "config": {"iterations": 30000, "seeds": len(deltas), "eval_episodes": 20,
                       "methods": preset_methods or ["bc-so", "bc-oh", "ours-step", "ours-softmax"]},
            "expert": {"return_mean": 2000.0, "return_std": 50.0, "random_return_mean": 0.0},
            "runs": runs, "summary": summary, "timing": {"total_s": 100.0},
            "system": {"jax": "0.9.2", "backend": "cpu", "devices": 1, "commit": "abc1234", "machine": "test CPU"}}


def _write(tmp_path, name, obj):
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return path


def _loaded(tmp_path, obj, name="r.json"):
    return report.load(_write(tmp_path, name, obj))


def _index(files, figure_dir=None):
    """The results page (`index.md`) of `files`: every table across tasks; figures written to `figure_dir` if given."""
    built = report.build(files, figure_dir)
    for path, fig in built.figures.items():
        figures.save_png(fig, path)
    return built.pages["index.md"].text


def _schema2(obj, command=None, methods=None, protocol=None):
    """A schema-1 fixture as the sweep writes schema 2: with its command, protocol (default brax's) and methods."""
    return {**obj, "schema": 2, "command": command, "protocol": protocol or {"name": "brax", "dt": 0.008},
            "methods": methods or {}, "config": {**obj["config"], "metric": "return", "task_metrics": []}}


def _fca(frame_skip=1, standard=4, train=20_000):
    """The fca family's protocol dict as `ape_jax.tasks.Protocol.settings` records it: `fca` at frame skip 1, else
    `fca-fs<N>`, 500 standard steps of simulated time, `train` / 4,000 training / validation transitions
    (`-train<N>k` in the name where `train` is not fca's 20,000)."""
    name = ("fca" if frame_skip == 1 else f"fca-fs{frame_skip}") + (
        "" if train == 20_000 else f"-train{train // 1000}k")
    return {"name": name, "frame_skip": frame_skip,
            "standard_frame_skip": standard, "episode_length": 500 * standard // frame_skip,
            "reward_scale": frame_skip / standard, "collect_transitions": max(50_000, train + 10_000),
            "train_transitions": train, "val_transitions": 4_000, "history": 2}


def _map_files(tmp_path, fs1=(600.0, 610.0, 1000.0), fs2=(600.0, 1000.0, 1100.0), fs4=(400.0, 1600.0, 1500.0),
               env="hopper"):
    """One task under fca at frame skips 1, 2, 4 (BC-SO, BC-OH, Ours at THR 10% W 5 returning `fsN`; the expert's
    2,000 is 100%) and under brax (schema 1, another expert): the copycat map's fixture. The frame-skip-1 file
    also holds a softmax τ, the FCA baseline and a third seed, which the map does not use."""
    def methods(bcso, bcoh, ours):
        return (("bc-so", {}, bcso), ("bc-oh", {}, bcoh), ("ours-step", {"thr": 0.1, "w": 5.0}, ours))

    files = [_schema2(_results(env, methods(*fs1) + (("ours-softmax", {"tau": 0.2}, 900.0),
                                                      ("fca", {"alpha": 0.1}, 1200.0)), deltas=(-10.0, 0.0, 10.0)),
                      protocol=_fca(1))]
    files += [_schema2(_results(env, methods(*fs)), protocol=_fca(skip)) for skip, fs in ((2, fs2), (4, fs4))]
    brax = _results(env)
    brax["expert"] = {"return_mean": 3000.0, "return_std": 80.0, "random_return_mean": 10.0}
    files.append(brax)
    return [_loaded(tmp_path, f, f"{env}-{i}.json") for i, f in enumerate(files)]


def test_the_report_merges_files_per_environment_and_builds_every_table(tmp_path):
    main = _write(tmp_path, "main.json", _results())
    base = _write(tmp_path, "base.json", _results(methods=(("fca", {"alpha": 0.1}, 1100.0),
                                                           ("dagger", {"rounds": 4, "budget": 100}, 1900.0)),
                                                  preset_methods=["fca", "dagger"]))
    text = report.report([report.load(main), report.load(base)])
    state = text[text.index("| method | Hopper |"):]
    assert "| BC-OH | 1,000 ± 14 (50%) |" in state           # ± the sample sd over the 2 seeds, 1,000 ∓ 10
    assert "| Ours, step THR 10% W 5 | 1,500 ± 14 (75%) |" in state
    assert "| Ours, best step | 1,600 ± 14 (80%) <br>(thr 0.2, w 3) |" in state     # the best, with its setting
    assert "| FCA (TCA) | 1,100 ± 14 (55%) |" in state and "| DAgger (online) | 1,900 ± 14 (95%) |" in state
    assert state.index("| DAgger (online) |") < state.index("| FCA (TCA) |")               # the registry's order
    assert "HistoryDropout" not in state                                               # in no file: no row
    # next to the paper: ratios to BC-OH within each source
    assert "| Ours, step THR 10% W 5 | 641 (2.19×) | 1,500 (1.50×) |" in text
    # provenance: a schema-1 file's command is rebuilt from its settings, and says so; with its commit and machine
    assert ("`python -m experiments.sweep --env hopper --obs pos --preset default --seeds 2` (rebuilt from its "
            "settings: the file predates results schema 2") in text
    assert "--methods fca,dagger" in text and "commit `abc1234`" in text and "test CPU" in text
    # fields added by experiments.evaluate are named with the commit that added them
    again = {**_results(), "reevaluated": {"fields": ["imitation_error", "rollout_ape"], "eval_s": 9.0,
                                           "system": {"commit": "def5678"}}}
    assert ("`imitation_error`, `rollout_ape` added later by `python -m experiments.evaluate` (commit `def5678`"
            in report.provenance(Results.from_json(again)))
    later = {**_results(), "reevaluated": {"fields": ["diagnostics.state_ratio"], "eval_s": 5.0,
                                           "system": {"commit": "0a1b2c3"}, "previous": again["reevaluated"]}}
    assert ("`imitation_error`, `rollout_ape` added later by `python -m experiments.evaluate` (commit `def5678`), "
            "then `diagnostics.state_ratio` (commit `0a1b2c3`, every recorded number reproduced)"
            in report.provenance(Results.from_json(later)))
    assert "100 s in all, peak resident memory 1.5 GB" in report.provenance(
        Results.from_json({**_results(), "timing": {"total_s": 100.0, "peak_rss_mb": 1536.0}}))
    assert "100 s in all (resumed after an interruption" in report.provenance(
        Results.from_json({**_results(), "timing": {"total_s": 100.0, "resumed": True}}))
    # the grid marks the best configuration; the loss table averages seeds
    assert "| **DAgger (online)** | rounds 4, budget 100 | 2 | **1,900.0 ± 14.1** | 95.0 |" in text
    assert "| BC-OH | 0.6000 | 0.3000 | 0.0500 | 0.6000 | 0.3000 | 0.0500 |" in text


def test_provenance_quotes_the_recorded_command():
    command = ["python", "-m", "experiments.sweep", "--env", "hopper", "--out", "runs/my sweep", "--seeds", "2"]
    line = report.provenance(Results.from_json(_schema2(_results(), command=command)))
    assert line.startswith("`python -m experiments.sweep --env hopper --out 'runs/my sweep' --seeds 2` — 30,000 "
                           "iterations, 2 seeds")
    assert "rebuilt" not in line and "schema" not in line
    # machine paths go: a run folder from its `runs/`, any other absolute path by its name
    command = ["python", "-m", "experiments.sweep", "--out", "/home/me/runs/s7/hopper", "--data-dir=/data/cache"]
    line = report.provenance(Results.from_json(_schema2(_results(), command=command)))
    assert line.startswith("`python -m experiments.sweep --out runs/s7/hopper --data-dir=cache` — ")
    from_python = report.provenance(Results.from_json(_schema2(_results())))   # schema 2, run from Python
    assert "--seeds 2` (rebuilt from its settings: the sweep ran from Python)" in from_python
    # a schema-3 one records its settings whole: it is given the arguments that resolve to them, its dataset too
    settings = resolve("hopper", "pos", "mujoco-state", "default", sets=["recipe.batch_size=32", "budget.seeds=2"])
    obj = _schema2(_results(), protocol=_fca(), methods={"bc-so": {}})
    obj = {**obj, "schema": 3, "preset": "default", "settings": settings.to_json(),
           "config": {**obj["config"], "methods": ["bc-so"], "data": {"settings": {"dataset": "my data.npz"}}}}
    assert report.provenance(Results.from_json(obj)).startswith(
        "`python -m experiments.sweep --env hopper --obs pos --preset default --set budget.seeds=2 "
        "--set recipe.batch_size=32 --methods bc-so --dataset 'my data.npz'` (rebuilt from its settings: the sweep "
        "ran from Python)")


def test_the_cli_writes_the_block_and_the_pages_and_keeps_the_hand_written_text(tmp_path, capsys):
    main = _write(tmp_path, "main.json", _results())
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\nhand-written prose\n")
    assert report.main([str(main), "--out", str(out)]) == 0
    first = out.read_text()
    assert "hand-written prose" in first and "<!-- report:start -->" in first
    assert "Every table: [the results](docs/results/index.md)." in first
    pages = tmp_path / "docs" / "results"
    assert sorted(p.name for p in pages.iterdir()) == ["hopper-pos.md", "index.md"]
    index, hopper = (pages / "index.md").read_text(), (pages / "hopper-pos.md").read_text()
    assert index.startswith("# Results\n\n<!-- report:start -->\n") and "| BC-SO | 300 ± 14 (15%) |" in index
    assert "| [Hopper, `pos` observations](hopper-pos.md) | 1 | 1 |" in index
    assert hopper.startswith("# Hopper, `pos` observations\n") and "## Protocol brax" in hopper
    assert "- [`main.json`](../../main.json): `python -m experiments.sweep" in hopper
    # text written by hand around a page's markers stays; regenerating changes nothing else
    (pages / "hopper-pos.md").write_text(hopper.replace("# Hopper, `pos` observations\n", "# Hopper\n\nnotes\n"))
    assert report.main([str(main), "--out", str(out)]) == 0
    assert out.read_text() == first and (pages / "index.md").read_text() == index
    assert (pages / "hopper-pos.md").read_text() == hopper.replace("# Hopper, `pos` observations\n",
                                                                   "# Hopper\n\nnotes\n")
    # --pages elsewhere, linked from the block; --pages without --out is refused
    assert report.main([str(main), "--out", str(out), "--pages", str(tmp_path / "site")]) == 0
    assert "Every table: [the results](site/index.md)." in out.read_text()
    with pytest.raises(SystemExit) as exc:
        report.main([str(main), "--pages", str(tmp_path / "site")])
    assert exc.value.code == 2 and "--pages" in capsys.readouterr().err


@pytest.mark.parametrize("content, message", [
    ("{not json", "not valid JSON"),
    ('{"schema": 1}', "not a sweep results file (missing env"),
    (None, "cannot read"),
])
def test_bad_results_files_are_refused_with_exit_code_2(tmp_path, capsys, content, message):
    path = tmp_path / "r.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(SystemExit) as exc:
        report.main([str(path)])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_a_smoke_run_is_refused_naming_it(tmp_path, capsys):
    res = _results()
    res["config"]["smoke"] = True
    path = _write(tmp_path, "smoke.json", res)
    with pytest.raises(SystemExit) as exc:
        report.main([str(path)])
    assert exc.value.code == 2 and f"{path}: a --smoke run" in capsys.readouterr().err


def test_the_same_configuration_in_two_files_is_refused(tmp_path, capsys):
    a, b = _write(tmp_path, "a.json", _results()), _write(tmp_path, "b.json", _results())
    with pytest.raises(SystemExit) as exc:
        report.main([str(a), str(b)])
    assert exc.value.code == 2 and "is also in another results file" in capsys.readouterr().err


# -- Ours − BC-OH: bootstrap over seeds --------------------------------------------------------------------------

def _seeds_from(obj, first):
    """`obj`'s runs numbered from seed `first`, as `--set budget.first_seed=first` numbers them."""
    obj = json.loads(json.dumps(obj))
    for run in obj["runs"]:
        run["seed"] += first
    return obj


def test_one_sweep_split_by_seeds_merges_into_the_rows_of_all_its_seeds(tmp_path, capsys):
    whole = report.merge([_loaded(tmp_path, _results(deltas=(-10.0, 10.0, 30.0, 70.0)), "whole.json")])
    parts = [_loaded(tmp_path, _results(deltas=(-10.0, 10.0)), "a.json"),
             _loaded(tmp_path, _seeds_from(_results(deltas=(30.0, 70.0)), 2), "b.json")]
    split = report.merge(parts)
    (w,), (s,) = whole.values(), split.values()
    assert len(s.runs) == 20 and sorted({r["seed"] for r in s.runs}) == [0, 1, 2, 3]
    expected = summarize(w.runs, ddof=1)  # all four seeds, ± their sample sd (the fixture's own rows are round)
    assert [(r["method"], r["hparams"]) for r in s.summary] == [(r["method"], r["hparams"]) for r in expected]
    for a, b in zip(s.summary, expected):
        assert a["n_seeds"] == b["n_seeds"] == 4
        assert a["return_mean"] == pytest.approx(b["return_mean"]) and a["return_std"] == pytest.approx(b["return_std"])
    bc_oh = next(r for r in s.summary if r["method"] == "bc-oh")
    assert bc_oh["return_mean"] == pytest.approx(1025.0)   # 1000 + mean(-10, 10, 30, 70), neither file's mean
    # the same seed twice, or the same configuration run with other settings, is refused
    with pytest.raises(report.ReportError, match="b.json: bc-so {} is also in another results file of .* "
                                                 "with seed\\(s\\) 1; pass one of them"):
        report.merge([parts[0], _loaded(tmp_path, _seeds_from(_results(deltas=(30.0, 70.0)), 1), "b.json")])
    other = _results(deltas=(30.0, 70.0))
    other["config"]["lr"] = 1e-3
    with pytest.raises(report.ReportError, match="c.json: bc-so {} is also in another results file .* with other "
                                                 "settings"):
        report.merge([parts[0], _loaded(tmp_path, _seeds_from(other, 2), "c.json")])


def test_a_method_trained_only_for_another_to_read_gives_way_to_the_groups_own_row(tmp_path):
    """Priming reads its file's BC-SO (`Method.reads`): where another file of the group trained BC-SO for its own
    sake on the same seeds, that one stands and the primed file's is set aside, said on its page; a BC-SO trained
    for its own sake twice is still refused."""
    def schema3(methods):   # a file as the sweep writes it, its settings whole (so its methods' knobs resolve)
        obj = _schema2(_results(methods=methods), protocol=_fca(), methods={m: {} for m, _, _ in methods})
        settings = resolve("hopper", "pos", "mujoco-state", "default", sets=["budget.seeds=2"])
        return {**obj, "schema": 3, "preset": "default", "settings": settings.to_json(),
                "config": {**obj["config"], "methods": [m for m, _, _ in methods]}}

    cell = _loaded(tmp_path, schema3((("bc-so", {}, 300.0), ("bc-oh", {}, 1000.0))), "cell.json")
    primed = schema3((("bc-so", {}, 320.0), ("priming", {"weight": 1.0}, 1100.0)))
    files = [_loaded(tmp_path, primed, "primed.json"), cell]
    (g,) = report.merge(files).values()
    bc_so = [r for r in g.runs if r["method"] == "bc-so"]
    assert [r["eval"]["return_mean"] for r in bc_so] == [290.0, 310.0]          # the cell's, not the primed file's
    assert {r["method"] for r in g.summary} == {"bc-so", "bc-oh", "priming"}
    assert g.set_aside == [(str(tmp_path / "primed.json"), "bc-so")]
    page = report.build(files).pages["hopper-pos.md"].text
    assert "Its bc-so, trained for another of its methods to read, is left out of the tables" in page
    alone = schema3((("bc-so", {}, 320.0), ("bc-oh", {}, 1100.0)))
    with pytest.raises(report.ReportError, match="bc-so {} is also in another results file"):
        report.merge([cell, _loaded(tmp_path, alone, "alone.json")])


def test_one_expert_measured_with_float_rounding_apart_merges_and_another_expert_is_refused(tmp_path):
    """The same deterministic expert measured by other code or on another CPU differs in the last digits of its
    return's sd (FCA's expert: 2.9826 against 2.9838); files that differ so are one group, other experts are not."""
    a = _loaded(tmp_path, _results(deltas=(-10.0, 10.0)), "a.json")
    b = _seeds_from(_results(deltas=(30.0, 70.0)), 2)
    b["expert"] = {**b["expert"], "return_std": b["expert"]["return_std"] * (1 + 4e-4)}
    (g,) = report.merge([a, _loaded(tmp_path, b, "b.json")]).values()
    assert len(g.sources) == 2 and len(g.runs) == 20
    other = _seeds_from(_results(deltas=(30.0, 70.0)), 2)
    other["expert"] = {**other["expert"], "return_mean": other["expert"]["return_mean"] * 1.01}
    with pytest.raises(report.ReportError, match="c.json: its expert differs from another"):
        report.merge([a, _loaded(tmp_path, other, "c.json")])


def test_the_bootstrap_ci_excludes_zero_for_a_clear_difference_and_contains_it_for_overlapping_seeds():
    ours, bcoh = [1000.0, 1012.0, 990.0], [500.0, 515.0, 480.0]
    ci = report.mean_difference(ours, bcoh)
    assert ci.diff == pytest.approx(1000.6667 - 498.3333, abs=1e-3) and (ci.n_a, ci.n_b) == (3, 3)
    assert 0 < ci.low <= ci.diff <= ci.high and report.verdict(ci) == "Ours better"
    assert report.verdict(report.mean_difference(bcoh, ours)) == "BC-OH better"
    overlap = report.mean_difference([100.0, 300.0, 200.0], [150.0, 260.0, 90.0])
    assert overlap.low < 0 < overlap.high
    assert report.verdict(overlap) == "not significant (CI contains 0)"
    # the CI is a fixed function of its inputs (fixed RNG seed), and one seed per arm gives no verdict
    assert report.mean_difference([100.0, 300.0, 200.0], [150.0, 260.0, 90.0]) == overlap
    assert report.verdict(report.mean_difference([5.0], [1.0])).startswith("no verdict")


def test_the_report_tabulates_the_bootstrap_per_environment(tmp_path):
    methods = (("bc-oh", {}, 1000.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 1500.0),
               ("ours-step", {"thr": 0.2, "w": 3.0}, 1005.0), ("ours-softmax", {"tau": 5.0}, 800.0))
    text = report.report([_loaded(tmp_path, _results(methods=methods))])
    # seeds are ret ± 10: Welch's interval with 2 degrees of freedom, 500 ± t(0.975, 2) · √(200 / 2 · 2) = ± 61
    assert ("| Hopper | Ours, step THR 10% W 5 (the paper's) − BC-OH | 2 / 2 | +500 (return) | [+439, +561] "
            "(2 seeds: wide) | Ours better |") in text
    assert ("| Hopper | Ours, best step (thr 0.1, w 5; selected after the fact) − BC-OH | 2 / 2 | +500 (return) | "
            "[+439, +561] (2 seeds: wide) | Ours better |") in text
    assert ("| Hopper | Ours, best softmax (tau 5; selected after the fact) − BC-OH | 2 / 2 | -200 (return) | "
            "[-261, -139] (2 seeds: wide) | BC-OH better |") in text
    assert "BC-OH − BC-SO" not in text.split("| task | comparison |")[1]    # no BC-SO in the fixture: no such row
    assert "95% Welch t-interval (down to 2 seeds per arm" in text
    close = report.report([_loaded(tmp_path, _results(methods=(("bc-oh", {}, 1000.0),
                                                               ("ours-step", {"thr": 0.1, "w": 5.0}, 1005.0))))])
    assert "| +5 (return) | [-56, +66] (2 seeds: wide) | not significant (CI contains 0) |" in close


# -- the grid search: the paper's choices -------------------------------------------------------------------------

def test_the_papers_settings_are_set_against_the_grids_best_in_numbers(tmp_path):
    """`analysis.choices` and `gap`: the numbers the paper-choice sentences are built from (the golden snapshot
    pins how they read)."""
    from experiments.report.analysis import choices, gap

    (m,) = report.merge([_loaded(tmp_path, _results())]).values()   # THR 10% W 5: 75%; THR 20% W 3: 80%
    step, softmax = choices(m)
    assert softmax.chosen is None and softmax.paper == {"tau": 0.2}   # it ran τ 5, not the paper's 0.2 (Hopper)
    assert step.kind == "step" and step.chosen["hparams"] == {"thr": 0.1, "w": 5.0}
    assert step.best["hparams"] == {"thr": 0.2, "w": 3.0} and step.closest is None
    g = gap(step.chosen, step.best, "normalized")
    sd = 0.5 ** 0.5  # the sample sd of 75 ∓ 0.5
    assert (*g.chosen, *g.best, g.gap, g.noise) == pytest.approx((75.0, sd, 80.0, sd, 5.0, sd))
    assert (g.is_best, g.within) == (False, False)

    methods = (("bc-oh", {}, 1000.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 1500.0),
               ("ours-step", {"thr": 0.2, "w": 3.0}, 1505.0),
               ("ours-softmax", {"tau": 0.2}, 100.0), ("ours-softmax", {"tau": 10.0}, 1400.0))
    r = _results(env="walker2d", methods=methods)
    r["config"]["ape"] = {"normalization": "mean", "scale": 0.025}
    (m,) = report.merge([_loaded(tmp_path, r)]).values()
    step, softmax = choices(m)
    assert gap(step.chosen, step.best, "normalized").gap == pytest.approx(0.25)
    assert gap(step.chosen, step.best, "normalized").within                    # 0.25 points, std 0.5
    # the paper's τ acts on raw APE: τ 0.2 ÷ 0.025 = 8 on this file's scale, nearest grid value τ 10 (the best)
    assert softmax.chosen["hparams"] == {"tau": 0.2} and softmax.scale == 0.025
    assert softmax.equivalent == pytest.approx(8.0) and softmax.closest is softmax.best
    assert softmax.best["hparams"] == {"tau": 10.0}
    assert gap(softmax.chosen, softmax.best, "normalized").gap == pytest.approx(65.0)
    text = report.report([_loaded(tmp_path, r)])
    assert ("| softmax, nearest the paper's τ on our APE scale (τ 8.0): τ 10 | 70.0 ± 0.7 | τ 10 | 70.0 ± 0.7 | 0.0 | "
            "0.7 | best |") in text   # the table shows those numbers


# -- figures ------------------------------------------------------------------------------------------------------

def _check_png(path):
    from PIL import Image

    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and 10_000 < len(data) < 150_000, (path, len(data))
    with Image.open(path) as image:
        image.verify()
    with Image.open(path) as image:
        width, height = image.size
    assert 500 <= width <= 2500 and 250 <= height <= 1500, (path, image.size)


def test_the_cli_draws_figures_next_to_out_and_links_them_relatively(tmp_path, capsys):
    main = _write(tmp_path, "main.json", _results())
    base = _write(tmp_path, "base.json", _results(methods=(("fca", {"alpha": 0.1}, 1100.0),
                                                           ("kmeans", {}, 1900.0)), preset_methods=["fca", "kmeans"]))
    walker = _write(tmp_path, "walker.json", _results(env="walker2d"))
    out = tmp_path / "docs" / "BENCHMARKS.md"
    out.parent.mkdir()
    assert report.main([str(main), str(base), str(walker), "--out", str(out)]) == 0
    figures = out.parent / "figures"
    assert sorted(p.name for p in figures.iterdir()) == ["grid-hopper.png", "grid-walker2d.png", "returns-other.png"]
    for png in figures.iterdir():
        _check_png(png)
    pages = out.parent / "docs" / "results"
    text = (pages / "index.md").read_text()
    assert "![Other protocols: Brax's own frame skip and episodes: every method per group](../../figures/" \
        "returns-other.png)" in text
    assert "![Hopper grid search](../../figures/grid-hopper.png)" in (pages / "hopper-pos.md").read_text()
    assert "](../../figures/grid-walker2d.png)" in (pages / "walker2d-pos.md").read_text()
    assert "wrote " + str(figures / "returns-other.png") in capsys.readouterr().out
    # deterministic: a second run gives the same markdown and the same PNG bytes
    first, png = text, (figures / "grid-hopper.png").read_bytes()
    assert report.main([str(main), str(base), str(walker), "--out", str(out)]) == 0
    assert (pages / "index.md").read_text() == first and (figures / "grid-hopper.png").read_bytes() == png
    # --figures elsewhere: links relative to each page's folder
    assert report.main([str(main), "--out", str(out), "--figures", str(tmp_path / "figs")]) == 0
    assert "![Hopper grid search](../../../figs/grid-hopper.png)" in (pages / "hopper-pos.md").read_text()
    _check_png(tmp_path / "figs" / "returns-other.png")


def test_printing_draws_figures_only_with_figures_dir(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main = _write(tmp_path, "main.json", _results())
    assert report.main([str(main)]) == 0
    printed = capsys.readouterr()
    assert "Figures not drawn" in printed.out and "![" not in printed.out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["main.json"]
    assert report.main([str(main), "--figures", "plots"]) == 0
    printed = capsys.readouterr()
    assert "](plots/grid-hopper.png)" in printed.out and "Figures not drawn" not in printed.out
    assert "wrote plots/returns-other.png" in printed.err             # stdout carries only the markdown
    _check_png(tmp_path / "plots" / "grid-hopper.png")


def test_a_figures_dir_that_cannot_be_written_is_refused_and_out_is_untouched(tmp_path, capsys):
    main = _write(tmp_path, "main.json", _results())
    (tmp_path / "file").write_text("")
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n")
    with pytest.raises(SystemExit) as exc:
        report.main([str(main), "--out", str(out), "--figures", str(tmp_path / "file")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"--figures {tmp_path / 'file'}: cannot write the figures" in err
    assert out.read_text() == "# Benchmarks\n" and not (tmp_path / "figures").exists()


def test_an_ok_run_without_its_evaluation_is_refused(tmp_path, capsys):
    r = _results()
    r["runs"][0].pop("eval")
    with pytest.raises(SystemExit) as exc:
        report.main([str(_write(tmp_path, "r.json", r))])
    assert exc.value.code == 2 and "runs[0] has no field 'eval'" in capsys.readouterr().err


def test_copycat_diagnostics_are_tabulated_for_runs_that_have_them(tmp_path):
    r = _results()
    r["config"]["ape"] = {"normalization": "mean", "scale": 0.02, "val_mean": 1.3}
    for run in r["runs"]:
        if run["method"] in ("bc-oh", "ours-step"):
            copycat = run["method"] == "bc-oh"
            run["eval"].update(rollout_ape=0.2 + 0.1 * run["seed"] if copycat else 0.9,
                               imitation_error=0.5 if copycat else 0.25)
    text = report.report([_loaded(tmp_path, r)])
    table = text[text.index("| method | hparams | seeds | rollout APE"):]
    assert "| expert (validation demonstrations) | — | — | 1.30 | 0 | 100 |" in table
    assert "| BC-OH | — | 2 | 0.250 | 0.5000 | 50.0 |" in table          # the mean over its two seeds
    assert "| Ours (step) | thr 0.1, w 5 | 2 | 0.900 | 0.2500 | 75.0 |" in table   # the registry's label
    assert "| BC-SO |" not in table                                        # no diagnostics recorded: left out
    assert "rollout APE" not in report.report([_loaded(tmp_path, _results(), "plain.json")])
    # trained on the raw APE: val_mean is raw, not on rollout_ape's scale (÷ the training mean), so no expert row
    r["config"]["ape"] = {"normalization": "none", "scale": 1.0, "val_mean": 0.03}
    table = report.report([_loaded(tmp_path, r, "raw.json")])
    table = table[table.index("| method | hparams | seeds | rollout APE"):]
    assert "expert (validation demonstrations)" not in table and "| BC-OH | — | 2 | 0.250 | 0.5000 | 50.0 |" in table


def test_the_sensitivity_study_sits_next_to_the_papers_numbers(tmp_path):
    methods = [("ours-softmax", {"tau": t}, ret) for t, ret in ((0.1, 700.0), (0.2, 760.0), (0.5, 730.0))] + \
              [("ours-step", {"thr": 0.1, "w": w}, ret) for w, ret in ((4.0, 800.0), (5.0, 1000.0), (6.0, 900.0))]
    text = report.report([_loaded(tmp_path, _results(env="walker2d", methods=methods))])
    table = text[text.index("## Sensitivity"):]
    assert "| softmax τ 0.2 | 760 ± 14 | 38.0 | Walker2d 769 ± 97 |" in table
    assert "| step THR 10%, W 6 | 900 ± 14 | 45.0 | driving 41.3% success |" in table
    assert "## Sensitivity" not in report.report([_loaded(tmp_path, _results(), "hopper.json")])


def test_training_curves_and_weight_histograms_are_drawn_from_files_that_record_them(tmp_path):
    from PIL import Image

    r = _results()
    r["config"]["ape"] = {"normalization": "mean", "scale": 0.02, "val_mean": 1.0,
                          "quantiles": [0.01 * 1.06 ** i for i in range(101)]}
    for run in r["runs"]:
        run["train_curve"] = [1.0 / (1 + i + run["seed"]) for i in range(100)]
    out = tmp_path / "B.md"
    assert report.main([str(_write(tmp_path, "r.json", r)), "--out", str(out)]) == 0
    text = (tmp_path / "docs" / "results" / "index.md").read_text()
    assert "![Training curves: Other protocols: Brax's own frame skip and episodes](../../figures/" \
        "curves-other.png)" in text
    assert "![Weight concentration within a batch, groups trained on the APE ÷ its mean](../../figures/" \
        "weights-by-mean.png)" in text
    # uniform weights: the heaviest of 128 carries 1/128, the heaviest 13 carry 13/128; the step setting's 10%
    # of samples at W 5 carry about 5·0.1 / (5·0.1 + 0.9) = 36%; a small τ gives one sample nearly everything
    assert "| Hopper | uniform (BC-OH) | 1% | 10% | 1% | 10% |" in text       # raw APE and ÷ its mean alike
    step = next(line for line in text.splitlines() if line.startswith("| Hopper | step THR 10% W 5 |"))
    assert 30 <= float(step.split("|")[4].strip(" %")) <= 42
    panel = report.weight_shares(report.merge([report.load(tmp_path / "r.json")]))[0]
    shares = {lab: raw for lab, raw, _ in panel.series}
    for y in (y for _, raw, by_mean in panel.series for y in (raw, by_mean)):
        assert np.all(np.diff(y) >= -1e-12) and abs(y[-1] - 1) < 1e-9    # cumulative shares, ending at all of it
    assert panel.trained == "mean"
    assert shares["softmax τ 5"][0] > shares["uniform (BC-OH)"][0]
    for name in ("curves-other.png", "weights-by-mean.png"):
        with Image.open(tmp_path / "figures" / name) as im:
            assert im.size[0] > 300 and im.size[1] > 200
    assert "Training curves" not in report.report([_loaded(tmp_path, _results(), "p.json")])  # older files: none


def test_image_results_and_a_task_judged_by_a_rate_get_their_tables(tmp_path):
    image = {**_results(), "obs": "image"}
    image["config"] = {**image["config"], "iterations": 5000}   # the image default preset's budget
    # the driving sandbox: judged by its success rate, its reward is 0 (found by its record, not by name)
    car = tasks.get(next(t for t in tasks.sweepable() if tasks.get(t).metric != "return"))
    assert car.metric == "success" and car.paper["bc-oh"] == (95.1, 4.5)
    sandbox = {**_results(env=car.name, methods=(("bc-so", {}, 0.0), ("bc-oh", {}, 0.0),
                                                  ("ours-step", {"thr": 0.1, "w": 5.0}, 0.0))), "obs": "image"}
    sandbox["expert"] = {"return_mean": None, "return_std": None, "random_return_mean": None}
    sandbox["config"] = {**sandbox["config"],   # its task's default preset budget
                         "iterations": resolve(car.name, "image", preset="default").budget.iterations}
    for run in sandbox["runs"]:  # as the sweep records it: normalized = 100 · success
        run["eval"].update(success=0.9 + 0.05 * run["seed"], red_light_violations=0.0, progress=0.8,
                           avg_speed=0.5, stuck=0.1 * run["seed"], normalized=100 * (0.9 + 0.05 * run["seed"]))
    for row in sandbox["summary"]:
        row.update(normalized_mean=92.5, normalized_std=2.5)
    text = report.report([_loaded(tmp_path, image, "image.json"), _loaded(tmp_path, sandbox, "sandbox.json")])
    img = text[text.index("## MuJoCo-Image"):]
    assert "| BC-OH | 1,000 ± 14 (50%) |" in img
    table = text[text.index(f"## {car.title} (the supplement's Table 4 protocol)"):]
    assert ("| method | seeds | success % | red-light violations | progress | average speed | stuck % | "
            "success % of all episodes [Wilson 95%] | paper: success % |") in table
    # mean ± sd over seeds, and the mean's t-interval over the two seeds (a share's clipped to [0, 100]); every
    # episode pooled: 0.90 and 0.95 of each seed's episodes
    episodes = [run["eval"]["episodes"] for run in sandbox["runs"] if run["method"] == "bc-oh"]
    pooled = stats.wilson(round(0.9 * episodes[0]) + round(0.95 * episodes[1]), sum(episodes))
    assert ("| BC-OH | 2 (intervals wide) | 92.50 ± 3.54 [60.73, 100.00] | 0.00 ± 0.00 [0.00, 0.00] | "
            "0.80 ± 0.00 [0.80, 0.80] | "
            f"0.50 ± 0.00 [0.50, 0.50] | 5.00 ± 7.07 [0.00, 68.53] | {100 * pooled.value:.2f} [{100 * pooled.low:.2f}, "
            f"{100 * pooled.high:.2f}] | 95.1 ± 4.5 |") in table
    assert "100 s in all" in table and "test CPU" in table   # the run's wall time, in its provenance
    assert "| Ours, step THR 10% W 5 | 2 (intervals wide) |" in table
    assert "97.8 ± 0.5" in table   # the paper's, from the task record
    # its measure is success, not its (zero) reward: in the grid table and the bootstrap
    assert "| method | hparams | seeds | success % |" in table
    assert "| Ours (step) | thr 0.1, w 5 | 2 | 92.5 ± 3.5 |" in table
    assert (f"| {car.title} (image) | Ours, step THR 10% W 5 (the paper's) − BC-OH | 2 / 2 | +0 (success, % points) |"
            in text)
    assert (f"| {car.title} (image) | BC-OH − BC-SO (does the history help?) | 2 / 2 | +0 (success, % points) |"
            in text)
    assert f"({car.title}: in success rate)" in text
    assert "MuJoCo-State" not in text


def test_the_first_image_presets_files_are_a_table_of_their_own_beside_todays_preset(tmp_path):
    first = {**_results(), "obs": "image"}
    first["config"] = {**first["config"], "iterations": 5000, "encoder": "small"}   # as the shipped files record it
    today = _schema2({**_results(methods=(("bc-so", {}, 600.0), ("bc-oh", {}, 1400.0))), "obs": "image"})
    budget = resolve("hopper", "image", preset="default")
    today["config"].update(iterations=budget.budget.iterations, preset_iterations=budget.budget.iterations)
    files = [_loaded(tmp_path, first, "first.json"), _loaded(tmp_path, today, "today.json")]
    assert [former_preset(f) for f in files] == ["first image preset", None]
    # a file that records its preset's 5,000 iterations ran the first preset too; today's with the small encoder
    # set by hand did not
    for iterations, former in ((5000, "first image preset"), (budget.budget.iterations, None)):
        obj = _schema2({**first, "config": {**first["config"], "preset_iterations": iterations}})
        assert former_preset(_loaded(tmp_path, obj, f"{iterations}.json")) == former
    text = report.report(files)
    now = text[text.index("## MuJoCo-Image\n"):text.index("## MuJoCo-Image, the first image preset")]
    old = text[text.index("## MuJoCo-Image, the first image preset"):]
    assert "| BC-OH | 1,400 ± 14 (70%) |" in now and "1,000 ± 14" not in now
    assert "| BC-OH | 1,000 ± 14 (50%) |" in old and "small conv encoder" in old
    assert "| Hopper (image, brax, first image preset) | BC-OH − BC-SO (does the history help?) |" in text
    assert ("`python -m experiments.sweep --env hopper --obs image --preset default` (rebuilt from its settings"
            in text and "`--preset default` being the first image preset then" in text)


def _sandbox(success, stuck, deltas=(0, 1, 2, 3, 4)):
    """A driving-sandbox results file: per method, per-seed success rates and stuck rates."""
    car = next(t for t in tasks.sweepable() if tasks.get(t).metric != "return")
    methods = (("bc-so", {}, 0.0), ("bc-oh", {}, 0.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 0.0))
    f = {**_results(env=car, methods=methods, deltas=deltas), "obs": "image"}
    f["expert"] = {"return_mean": None, "return_std": None, "random_return_mean": None}
    f["config"] = {**f["config"], "iterations": resolve(car, "image", preset="default").budget.iterations}
    for run in f["runs"]:
        run["eval"].update(episodes=200, success=success[run["method"]][run["seed"]], red_light_violations=0.0,
                           progress=1.0, avg_speed=7.0, stuck=stuck[run["method"]][run["seed"]])
    return f


def test_the_sandbox_reading_says_whether_ours_beats_bc_oh_and_whether_inertia_appears(tmp_path):
    """`analysis.rate_reading`: the numbers of a rate-judged task's reading (the golden snapshot pins its words)."""
    from experiments.report.analysis import rate_reading, verdict

    success = {"bc-so": [0.92, 0.93, 0.91, 0.94, 0.92], "bc-oh": [0.80, 0.82, 0.79, 0.81, 0.80],
               "ours-step": [0.88, 0.90, 0.89, 0.87, 0.91]}
    stuck = {"bc-so": [0.0] * 5, "bc-oh": [0.05, 0.0, 0.1, 0.05, 0.0], "ours-step": [0.0] * 5}
    (m,) = report.merge([_loaded(tmp_path, _sandbox(success, stuck))]).values()
    r = rate_reading(m)
    assert r.metric == "success" and r.episodes == 200 and r.learned
    assert r.bcso == pytest.approx((92.4, 91.0, 93.8, 5), abs=0.05)   # Student's t over the 5 seeds
    (a, b, history), (c, d, ours) = r.differences
    assert (a, b, c, d) == ("bc-oh", "bc-so", "ours-step", "bc-oh")
    assert (history.diff, history.low, history.high) == pytest.approx((-12.0, -13.7, -10.3), abs=0.05)
    assert verdict(history, "BC-OH", "BC-SO") == "BC-SO better"
    assert ours.diff == pytest.approx(8.6) and verdict(ours) == "Ours better"
    assert r.inertia.mean == pytest.approx(4.0) and r.others == {"bc-so": 0.0, "ours-step": 0.0}
    # the same seeds with no stuck episode, and an unlearned BC-SO
    flat = {k: [0.0] * 5 for k in stuck}
    (m,) = report.merge([_loaded(tmp_path, _sandbox({**success, "bc-so": [0.80] * 5}, flat), "flat.json")]).values()
    r = rate_reading(m)
    assert r.bcso.mean == pytest.approx(80.0) and not r.learned and r.inertia.mean == 0.0
    # a task judged by a return has no such reading
    assert rate_reading(next(iter(report.merge([_loaded(tmp_path, _results(), "ret.json")]).values()))) is None


def test_a_plugin_and_the_baselines_are_listed_by_their_recorded_labels(tmp_path):
    """A method the registry does not know appears in the tables and the returns figure under the label its
    results file records; online methods say so, by their flag; baselines come first, in the registry's order."""
    main = _results()
    walker = _results(env="walker2d")
    info = {"my-plugin": {"label": "My plugin", "role": "plugin", "program": "grid", "online": False},
            "my-online": {"label": "My online plugin", "role": "plugin", "program": "online", "online": True}}
    extra = _schema2(_results(methods=(("my-plugin", {"thr": 0.1, "w": 5.0}, 1700.0), ("fca", {"alpha": 0.1}, 1100.0),
                                       ("my-online", {}, 1300.0), ("dagger", {"rounds": 4.0}, 1900.0)),
                              preset_methods=["my-plugin", "fca", "my-online", "dagger"]),
                     command=["python", "-m", "experiments.sweep", "--env", "hopper", "--plugins", "my_plugin"],
                     methods=info)
    files = [_loaded(tmp_path, main, "main.json"), _loaded(tmp_path, extra, "extra.json"),
             _loaded(tmp_path, walker, "walker.json")]
    text = report.report(files)
    state = text[text.index("| method | Hopper | Walker2d |"):]
    rows = [line.split(" | ")[0][2:] for line in state.splitlines()[2:13]]
    assert rows[5:] == ["DAgger (online)", "FCA (TCA)", "My plugin", "My online plugin (online)", "expert (ours)",
                        "random policy"]
    assert "| My plugin | 1,700 ± 14 (85%) | — |" in state        # not run on Walker2d: a dash
    assert "| My online plugin (online) | 1,300 ± 14 (65%) | — |" in state
    assert "| My plugin | thr 0.1, w 5 | 2 | 1,700.0 ± 14.1 | 85.0 |" in text        # the grid table
    assert "`python -m experiments.sweep --env hopper --plugins my_plugin` — " in text   # its recorded command
    merged = report.merge(files)
    (family,) = figures.families(figures.returns_groups(merged))
    fig = figures.returns_figure(family, merged)
    labels = [t.get_text() for t in fig.axes[0].get_yticklabels()]
    assert labels == ["BC-SO", "BC-OH", "Ours, step THR 10% W 5", "Ours, best softmax", "DAgger", "FCA (TCA)",
                      "My plugin", "My online plugin"]


def test_python_m_experiments_report_runs(tmp_path):
    path = _write(tmp_path, "r.json", _results())
    root = pathlib.Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-m", "experiments.report", str(path)], cwd=root, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "| BC-SO | 300 ± 14 (15%) |" in done.stdout


# -- protocols: fca, its other frame skips, brax -----------------------------------------------------------------

def test_fca_and_brax_results_of_one_task_are_merged_apart_into_two_tables(tmp_path, capsys):
    files = _map_files(tmp_path)
    merged = report.merge(files)
    assert sorted(merged) == sorted([("hopper", "pos", p, None, None, None)
                                     for p in ("mujoco-state", "mujoco-state-fs2", "mujoco-state-fs4", "brax")])
    assert merged[("hopper", "pos", "brax", None, None, None)].expert["return_mean"] == 3000.0  # its own expert
    assert [m.title for m in merged.values()] == ["Hopper (mujoco-state)", "Hopper (mujoco-state, frame skip 2)",
                                                     "Hopper (mujoco-state, frame skip 4)", "Hopper (brax)"]
    text = report.report(files)
    index = _index(files)
    fca = index[index.index("## MuJoCo-State, the paper's protocol (mujoco-state)\n\nFrame skip 1, 500 standard steps "
                            "of simulated time, 20,000 training transitions, split"):
                index.index("## MuJoCo-State, Brax's")]
    brax = index[index.index("## MuJoCo-State, Brax's frame skip (the project's first results)"):
                 index.index("## The copycat map")]
    assert "| BC-SO | 600 ± 10 (30%) |" in fca and "| FCA (TCA) | 1,200 ± 10 (60%) |" in fca
    assert "| BC-SO | 300 ± 14 (15%) |" in brax and "| expert (ours) | 3,000 ± 80 |" in brax
    assert index.count("| method | Hopper |") == 2         # frame skips 2 and 4 get no state table: they feed the map
    assert "| Hopper (mujoco-state) | BC-OH − BC-SO (does the history help?) | 3 / 3 |" in text
    assert "| Hopper (brax) | BC-OH − BC-SO (does the history help?) | 2 / 2 | +700 (return) |" in text
    assert "## Protocol mujoco-state, frame skip 4\n" in text
    assert ("protocol mujoco-state-fs2, frame skip 2 (the environment's own: 4), 1,000-step episodes, 20,000 training "
            "transitions; commit") in text
    assert "protocol brax (not recorded: results schema 1 predates protocols" in text
    # within one group the same configuration twice, or another expert or frame skip, is still refused
    again = [_schema2(_results(), protocol=_fca(1)), _schema2(_results(), protocol=_fca(1))]
    with pytest.raises(report.ReportError,
                       match="is also in another results file of hopper \\(pos, protocol mujoco-state\\)"):
        report.merge([_loaded(tmp_path, r, f"again{i}.json") for i, r in enumerate(again)])
    other = _schema2(_results(methods=(("fca", {"alpha": 0.1}, 1.0),)), protocol={**_fca(1), "frame_skip": 2})
    with pytest.raises(report.ReportError, match="its protocol differs .* \\(frame_skip 2 vs 1"):
        report.merge([files[0], _loaded(tmp_path, other, "other.json")])
    bad = _schema2(_results(), protocol={**_fca(1), "frame_skip": "1"})
    with pytest.raises(SystemExit) as exc:
        report.main([str(_write(tmp_path, "bad.json", bad))])
    assert exc.value.code == 2 and "protocol field 'frame_skip' must be an int >= 1" in capsys.readouterr().err


def test_the_fca_table_shows_the_papers_returns_beside_ours_on_one_scale(tmp_path):
    text = _index(_map_files(tmp_path))
    table = text[text.index("The supplement's Table 5 beside ours: mean return (the paper's scale)"):
                 text.index("## MuJoCo-State, Brax's")]
    # absolute returns side by side, ours ± std over seeds; the ratio to BC-OH of each source in brackets
    assert "| BC-SO | 275 (0.94×) | 600 ± 10 (0.98×) |" in table
    assert "| BC-OH | 293 (1.00×) | 610 ± 10 (1.00×) |" in table
    assert "| FCA (TCA) | 1,086 (3.71×) | 1,200 ± 10 (1.97×) |" in table
    assert "| Ours, step THR 10% W 5 | 641 (2.19×) | 1,000 ± 10 (1.64×) |" in table
    assert "| expert | not published | 2,000 |" in table
    # under brax only the ratios compare: no ±, no expert row
    brax = text[text.index("The supplement's Table 5 beside ours: mean return (other scales"):
                text.index("## The copycat map")]
    assert "| BC-SO | 275 (0.94×) | 300 (0.30×) |" in brax and "not published" not in brax


def test_the_copycat_map_gives_each_frame_skip_its_row_and_gaps(tmp_path):
    files = _map_files(tmp_path)
    (cm,) = report.copycat_map(report.merge(files))
    assert cm.title == "Hopper" and [(r.frame_skip, r.protocol) for r in cm.rows] == [
        (1, "mujoco-state"), (2, "mujoco-state-fs2"), (4, "mujoco-state-fs4")]
    # % of expert = return / 20; the frame-skip-1 file's softmax and FCA rows and its third seed are not the map's
    assert [[c.mean for c in r.cells] for r in cm.rows] == [[30.0, 30.5, 50.0], [30.0, 50.0, 55.0],
                                                            [20.0, 80.0, 75.0]]
    assert [[c.n for c in r.cells] for r in cm.rows] == [[3, 3, 3], [2, 2, 2], [2, 2, 2]]
    assert [r.history for r in cm.rows] == [0.5, 20.0, 60.0] and [r.ceiling for r in cm.rows] == [69.5, 50.0, 20.0]
    # two seeds at ±0.5 points per arm: Welch's half width t(0.975, 2) · √(0.5 / 2 · 2) = 3.04
    assert [x for r in cm.rows[1:] for x in (r.history_ci.low, r.history_ci.high)] == pytest.approx(
        [16.957, 23.043, 56.957, 63.043], abs=1e-3)
    assert cm.rows[0].history_ci == report.mean_difference([30.0, 30.5, 31.0], [29.5, 30.0, 30.5])
    text = report.report(files)
    assert ("| Hopper | 2 | 20,000 | mujoco-state-fs2 | 30.0 ± 0.7 | 50.0 ± 0.7 | 55.0 ± 0.7 | 2 / 2 / 2 | "
            "+20.0 [+17.0, +23.0] (2 seeds: wide) | 50.0 |") in text
    low, high = cm.rows[0].history_ci.low, cm.rows[0].history_ci.high
    assert low < 0 < high   # at frame skip 1 the history is not significant; at 2 and 4 it is
    # one frame skip of the family is no map
    assert report.copycat_map(report.merge([files[0], files[3]])) == []
    assert "The copycat map" not in report.report([files[0], files[3]])


def test_figure_names_are_unique_per_protocol(tmp_path):
    files = _map_files(tmp_path)
    out = tmp_path / "B.md"
    assert report.main([src.path for src in files] + ["--out", str(out)]) == 0
    names = sorted(p.name for p in (tmp_path / "figures").iterdir())
    assert names == ["copycat-map.png", "grid-hopper-mujoco-state-fs2.png", "grid-hopper-mujoco-state-fs4.png",
                     "grid-hopper-mujoco-state.png", "grid-hopper.png", "returns-first.png", "returns-other.png"]
    _check_png(tmp_path / "figures" / "copycat-map.png")
    assert "![The copycat map: % of expert per frame skip](figures/copycat-map.png)" in out.read_text()
    text = (tmp_path / "docs" / "results" / "hopper-pos.md").read_text()
    assert "![Hopper (mujoco-state, frame skip 2) grid search](../../figures/grid-hopper-mujoco-state-fs2.png)" in text
    assert "![Hopper (brax) grid search](../../figures/grid-hopper.png)" in text     # brax keeps its name
    fig = figures.copycat_map_figure(report.copycat_map(report.merge(files)))
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["1", "2", "4"] and ax.get_xscale() == "log"
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["BC-SO", "BC-OH", "Ours, step THR 10% W 5"]


def _ape_file(quantiles, normalization="none", scale=1.0, protocol=None):
    r = _results(methods=(("bc-oh", {}, 1000.0), ("ours-softmax", {"tau": 0.1}, 1100.0)))
    r["config"]["ape"] = {"normalization": normalization, "scale": scale, "val_mean": 1.0,
                          "quantiles": list(quantiles)}
    return _schema2(r, protocol=protocol or _fca(1))


def test_the_weight_table_compares_raw_and_mean_normalised_ape(tmp_path):
    # every sample's APE equal: softmax weights are uniform on both scales, like BC-OH's
    flat = report.weight_shares(report.merge([_loaded(tmp_path, _ape_file([0.02] * 101), "flat.json")]))
    (soft, step, uniform) = flat[0].series
    for y in (soft[1], soft[2], uniform[1]):
        np.testing.assert_allclose(y, np.arange(1, 129) / 128)
    # raw APE spread evenly over [0, 0.02] (mean 0.01): at τ 0.1 the raw APE's weights stay within e^0.2 of each
    # other, while ÷ its mean (× 100) they span e^20 and a few samples carry most of the batch
    spread = _loaded(tmp_path, _ape_file(np.linspace(0, 0.02, 101)), "spread.json")
    (w,) = report.weight_shares(report.merge([spread]))
    assert w.trained == "none" and w.mean_ape == pytest.approx(0.01) and not w.mean_recorded
    label, raw, by_mean = w.series[0]
    assert label == "softmax τ 0.1" and raw[0] < np.exp(0.2) / 128 and by_mean[0] > 0.1 and by_mean[12] > 0.5
    assert np.array_equal(w.series[1][1], w.series[1][2])             # the step weights depend on ranks only
    text = report.report([spread])
    row = (f"| Hopper (mujoco-state) | softmax τ 0.1 | 1% | {100 * raw[12]:.0f}% | {100 * by_mean[0]:.0f}% | "
           f"{100 * by_mean[12]:.0f}% |")
    assert row in text
    raw_ape = report.analysis.APE_SCALES["none"]
    assert f"| Hopper (mujoco-state) | `normalization: none`, the {raw_ape} | 0.01 (estimated) |" in text
    # the same raw APE recorded as a mean-normalised run records it (÷ its mean 0.01): the same weights
    by_scale = _loaded(tmp_path, _ape_file(np.linspace(0, 2, 101), "mean", 0.01), "mean.json")
    (m,) = report.weight_shares(report.merge([by_scale]))
    assert m.trained == "mean" and m.mean_recorded and m.mean_ape == 0.01
    for (_, a_raw, a_mean), (_, b_raw, b_mean) in zip(w.series, m.series):
        np.testing.assert_allclose(a_raw, b_raw)
        np.testing.assert_allclose(a_mean, b_mean)


def test_the_numbers_of_the_fca_reading_follow_the_verdicts(tmp_path):
    """The numbers the readings of the paper's protocol rest on: `analysis.history_difference` (does the history
    help?), `ours_differences` (does keyframe weighting beat BC-OH, at the paper's setting and at the best of the
    grids?) and their verdicts, which flip with the returns."""
    from experiments.report.analysis import Key, history_difference, ours_differences, verdict

    def fca_group(files):
        return report.merge(files)[Key("hopper", "pos", "mujoco-state")]

    # BC-OH ≈ BC-SO under fca: the return signature of copycat; Ours well above BC-OH
    m = fca_group(_map_files(tmp_path))
    history = history_difference(m)
    assert history.diff == pytest.approx(10.0) and history == report.mean_difference([600.0, 610.0, 620.0],
                                                                                          [590.0, 600.0, 610.0])
    assert verdict(history, "BC-OH", "BC-SO").startswith("not significant")
    (label, row, paper), *grids = ours_differences(m)
    assert row["hparams"] == {"thr": 0.1, "w": 5.0} and paper.diff == pytest.approx(390.0) and \
        verdict(paper) == "Ours better"
    # the history helping under fca, and Ours below BC-OH: the verdicts flip
    m = fca_group(_map_files(tmp_path, fs1=(300.0, 1000.0, 900.0)))
    assert verdict(history_difference(m), "BC-OH", "BC-SO") == "BC-OH better"
    assert verdict(ours_differences(m)[0][2]) == "BC-OH better"
    # the best of the grids is the softmax τ 0.2 row here, below BC-OH
    best = max(ours_differences(fca_group(_map_files(tmp_path, fs1=(600.0, 610.0, 500.0))))[1:],
               key=lambda x: x[2].diff)
    assert best[1]["hparams"] == {"tau": 0.2} and best[2].diff == pytest.approx(290.0)
    tie = ours_differences(fca_group(_map_files(tmp_path, fs1=(600.0, 610.0, 615.0))))[0][2]
    assert verdict(tie).startswith("not significant")


def test_the_sensitivity_study_reads_the_brax_group_of_walker2d(tmp_path):
    methods = [("ours-softmax", {"tau": t}, 700.0) for t in (0.1, 0.2, 0.5)]
    brax = _loaded(tmp_path, _results(env="walker2d", methods=methods), "brax.json")
    fca = _loaded(tmp_path, _schema2(_results(env="walker2d", methods=[("ours-softmax", {"tau": 0.2}, 1500.0)]),
                                     protocol=_fca(1)), "fca.json")
    table = report.report([fca, brax])
    table = table[table.index("## Sensitivity"):]
    assert "Walker2d (states, protocol brax)" in table and "| softmax τ 0.2 | 700 ± 14 | 35.0 |" in table


def test_the_experts_rollout_ape_reference_is_put_on_the_raw_training_means_scale():
    """`rollout_ape` is ÷ the raw training mean: a `"mean"` file's val_mean is on that scale already; a `"none"`
    file's (raw) needs its recorded `raw_mean`, and without it gives no reference rather than a wrong one."""
    from experiments.report import analysis

    def group(ape):
        res = Results.from_json({**_results(), "config": {**_results()["config"], "ape": ape}})
        (m,) = report.merge([res]).values()
        return m

    assert analysis.expert_ape(group({"normalization": "mean", "scale": 0.02, "val_mean": 1.3})) == 1.3
    assert analysis.expert_ape(group({"normalization": "none", "scale": 1.0, "val_mean": 0.026,
                                      "raw_mean": 0.02})) == pytest.approx(1.3)
    assert analysis.expert_ape(group({"normalization": "none", "scale": 1.0, "val_mean": 0.026})) is None


def test_a_longer_run_is_its_own_group_compared_configuration_by_configuration(tmp_path):
    """A sweep at more iterations than its preset's (`--iterations`) repeats configurations of the preset-budget
    files without colliding with them: its own group, title and figure, and a "Training longer" row per
    configuration both ran; the map and the state table keep reading the preset-budget group."""
    files = _map_files(tmp_path)
    long = _results("hopper", (("bc-oh", {}, 700.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 1300.0)))
    long["config"] = {**long["config"], "iterations": 100_000}
    files.append(_loaded(tmp_path, _schema2(long, protocol=_fca(1)), "long.json"))
    merged = report.merge(files)
    key = ("hopper", "pos", "mujoco-state", 100_000, None, None)
    assert key in merged and merged[key].title == "Hopper (mujoco-state, 100,000 iterations)"
    text = _index(files, tmp_path / "figures")
    section = text[text.index("## Training longer"):]
    assert ("| Hopper (mujoco-state, 100,000 iterations): configuration | 30,000 iterations | seeds | "
            "100,000 iterations |") in section
    assert "| BC-OH | 610 ± 10 (30%) | 3 | 700 ± 14 (35%) | 2 |" in section
    assert "| Ours (step), THR 10% W 5 | 1,000 ± 10 (50%) | 3 | 1,300 ± 14 (65%) | 2 |" in section
    assert (tmp_path / "figures" / "grid-hopper-mujoco-state-100000it.png").exists()
    assert "| BC-OH | 610 ± 10 (30%) |" in text[text.index("## MuJoCo-State, the paper's protocol"):]



def test_the_copycat_map_adds_training_set_sizes_at_frame_skip_1(tmp_path):
    """fca-train5k / fca-train80k files give the map rows at frame skip 1 by training-set size (fca's own 20,000
    among them), apart from the frame-skip rows, in the table and a second figure panel."""
    files = _map_files(tmp_path)
    for i, (train, rets) in enumerate(((5_000, (500.0, 480.0, 520.0)), (80_000, (700.0, 1500.0, 1600.0)))):
        obj = _results("hopper", (("bc-so", {}, rets[0]), ("bc-oh", {}, rets[1]),
                                  ("ours-step", {"thr": 0.1, "w": 5.0}, rets[2])))
        files.append(_loaded(tmp_path, _schema2(obj, protocol=_fca(1, train=train)), f"data{i}.json"))
    (cm,) = report.copycat_map(report.merge(files))
    assert [r.frame_skip for r in cm.rows] == [1, 2, 4]                      # the frame-skip rows are unchanged
    assert [(r.train_transitions, r.protocol) for r in cm.data_rows] == [
        (5_000, "mujoco-state-train5k"), (20_000, "mujoco-state"), (80_000, "mujoco-state-train80k")]
    assert [r.history for r in cm.data_rows] == [-1.0, 0.5, 40.0]
    assert [r.cells[1].mean for r in cm.data_rows] == pytest.approx([24.0, 30.5, 75.0])   # BC-OH per size
    text = _index(files, tmp_path / "figures")
    assert "| Hopper | 1 | 80,000 | mujoco-state-train80k | 35.0 ± 0.7 | 75.0 ± 0.7 | 80.0 ± 0.7 |" in text
    assert text.count("| Hopper | 1 | 20,000 | mujoco-state |") == 1          # its row once
    assert (tmp_path / "figures" / "copycat-map.png").exists()
    assert "## Protocol mujoco-state, 80,000 training transitions\n" in report.report(files)
    assert (tmp_path / "figures" / "grid-hopper-mujoco-state-train80k.png").exists()


def test_no_grid_beside_the_papers_setting_selects_no_best_of_it(tmp_path):
    """A sweep of BC-SO, BC-OH and the paper's step setting alone selected nothing: its only step row is the paper's."""
    from experiments.report.analysis import Key, ours_differences

    only = _results("hopper", (("bc-so", {}, 600.0), ("bc-oh", {}, 610.0),
                               ("ours-step", {"thr": 0.1, "w": 5.0}, 1000.0)))
    m = report.merge([_loaded(tmp_path, _schema2(only, protocol=_fca(1)), "only.json")])[
        Key("hopper", "pos", "mujoco-state")]
    ours = ours_differences(m)
    assert ours[0][2].diff == pytest.approx(390.0) and all(row is ours[0][1] for _, row, _ in ours)


def test_every_method_is_compared_with_bc_oh_under_fca_in_a_table(tmp_path):
    """Under fca each row of the state table but BC-OH gets `row − BC-OH` with its bootstrap CI (bold when the
    interval excludes 0, either way); a method BC-OH never ran beside gets a dash."""
    base = _results("hopper", (("bc-so", {}, 600.0), ("bc-oh", {}, 610.0),
                               ("ours-step", {"thr": 0.1, "w": 5.0}, 615.0),
                               ("fca", {"alpha": 0.1}, 900.0), ("kmeans", {"k": 6}, 300.0),
                               ("actfreq", {"bins": 5}, 612.0), ("boosting", {"rounds": 3}, 400.0)),
                   deltas=(-10.0, 0.0, 10.0))
    cheetah = _results("halfcheetah", (("bc-so", {}, 600.0), ("fca", {"alpha": 0.5}, 700.0)))
    files = [_loaded(tmp_path, _schema2(base, protocol=_fca(1)), "hopper.json"),
             _loaded(tmp_path, _schema2(cheetah, protocol=_fca(1)), "cheetah.json")]
    text = report.report(files)
    table = text[text.index("| method − BC-OH |"):]
    table = table[:table.index("\n\n")]
    fca, kmeans, actfreq = (report.mean_difference([v + d for d in (-10.0, 0.0, 10.0)],
                                                        [600.0, 610.0, 620.0]) for v in (900.0, 300.0, 612.0))
    assert f"| FCA (TCA) | **{fca.diff:+,.0f} [{fca.low:+,.0f}, {fca.high:+,.0f}]** | — |" in table
    assert f"| k-means | **{kmeans.diff:+,.0f} [{kmeans.low:+,.0f}, {kmeans.high:+,.0f}]** | — |" in table
    assert f"| ActFreq | {actfreq.diff:+,.0f} [{actfreq.low:+,.0f}, {actfreq.high:+,.0f}] | — |" in table
    assert "| BC-OH |" not in table
    boosting = report.mean_difference([390.0, 400.0, 410.0], [600.0, 610.0, 620.0])
    assert f"| Boosting | **{boosting.diff:+,.0f} [{boosting.low:+,.0f}, {boosting.high:+,.0f}]** | — |" in table
    # no BC-OH under a protocol: no table for it
    assert "| method − BC-OH |" not in report.report([files[1]])


def _schema3(obj, recipe, split="rows"):
    """A fixture as a schema-3 sweep under fca writes it: the protocol split by `split`, trained with `recipe`."""
    from ape_jax.pipeline.presets import resolve

    settings = resolve("hopper", "pos", preset="default", recipe=recipe, sets=[f"protocol.split={split}"]).to_json()
    return {**_schema2(obj, protocol={**_fca(), "split": split}), "schema": 3, "settings": settings}


def test_the_recipe_table_compares_recipes_under_one_protocol_apart_from_the_whole_episode_results(tmp_path):
    from experiments.report.analysis import recipe_groups, recipe_rows

    methods = (("bc-so", {}, 300.0), ("bc-oh", {}, 1000.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 900.0),
               ("fca", {"alpha": 2.0, "adversary_lr": 4e-4}, 800.0),
               ("fca", {"alpha": 0.1, "adversary_lr": 4e-4}, 1100.0))
    mlp = _schema3(_results(methods=methods, deltas=(-10.0, 0.0, 10.0)), "mlp")
    fca = _schema3(_results(methods=tuple((m, hp, r + 400.0) for m, hp, r in methods), deltas=(-10.0, 0.0, 10.0)),
                   "fca")
    for run in fca["runs"]:
        if run["method"] == "fca":
            run["train_final"] = {"adversary_loss": 0.5, "reference_loss": 0.6}
    old = _schema2(_results(), protocol=_fca())   # the committed whole-episode fca results: the mlp recipe
    files = [_loaded(tmp_path, f, name) for f, name in ((mlp, "m.json"), (fca, "f.json"), (old, "o.json"))]
    merged = report.merge(files)
    assert sorted(k.protocol for k in merged) == ["mujoco-state", "mujoco-state.rows.bn-mlp", "mujoco-state.rows.mlp"]
    groups = recipe_groups(merged)
    assert list(groups) == [("hopper", "pos", "mujoco-state, split by rows")] and set(groups[next(iter(groups))]) == \
        {"mlp", "bn-mlp"}
    rows = {r.label: r for r in recipe_rows(groups[("hopper", "pos", "mujoco-state, split by rows")])}
    assert list(rows) == ["BC-SO", "BC-OH", "Ours, step THR 10% W 5", "FCA (TCA)"]
    assert rows["BC-OH"].cells["mlp"].mean == pytest.approx(50.0) and rows["BC-OH"].cells["bn-mlp"].mean == \
        pytest.approx(70.0)
    assert rows["BC-OH"].difference.diff == pytest.approx(20.0) and rows["BC-OH"].difference.low > 0
    assert rows["FCA (TCA)"].cells["mlp"].mean == pytest.approx(40.0)   # the task's α (Hopper: 2.0), not the best
    text = report.build(files).pages["index.md"].text
    assert "## The paper's recipe" in text and "| BC-OH | 50.0 [48.8, 51.2] | 70.0 [68.8, 71.2] | **+20.0" in text
    assert "| bn-mlp | BC-OH − BC-SO | **+35.0" in text
    assert "| fca | alpha 0.1, adversary_lr 0.0004 | 55.0 [53.8, 56.2] | — | — |" in text   # recipe mlp
    assert "| fca | alpha 2, adversary_lr 0.0004 | 60.0 [58.8, 61.2] | 0.5 | 0.6 |" in text
    assert "## MuJoCo-State, the paper's protocol (mujoco-state)" in text   # the whole-episode files keep their tables


def test_a_rate_pools_every_episode_with_wilsons_interval():
    """ToyCar's success: 5 of 10 and 10 of 10 episodes are 15 of 20, Wilson's interval around 0.75."""
    from experiments.report.sections.task_metrics import wilson_cell

    runs = [{"eval": {"success": 0.5, "episodes": 10}}, {"eval": {"success": 1.0, "episodes": 10}}]
    e = stats.wilson(15, 20)
    assert wilson_cell(runs, "success") == f"75.00 [{100 * e.low:.2f}, {100 * e.high:.2f}]"
    assert 0.5 < e.low < 0.75 < e.high < 0.95
    assert wilson_cell([{"eval": {"return_mean": 1.0}}], "success") == "—"


ROOT = pathlib.Path(__file__).resolve().parents[1]


def _section(text: str) -> str:
    """What a file holds between `<!-- report:start -->` and `<!-- report:end -->`."""
    start, end = "<!-- report:start -->\n", "<!-- report:end -->"
    return text[text.index(start) + len(start):text.index(end)]


def test_the_committed_report_is_what_the_committed_results_give(tmp_path):
    """Golden snapshot: `build` over the committed `results/*.json` gives BENCHMARKS.md's block and every page of
    docs/results/ byte for byte (as `python -m experiments.report results/*.json --out BENCHMARKS.md` wrote them),
    no page more or less (but the hand-written notes.md), and draws exactly the committed figures (here into
    `tmp_path`, where `build` writes nothing)."""
    (tmp_path / "results").symlink_to(ROOT / "results")   # the links as from the root: ../../results/NAME
    files = [report.load(tmp_path / "results" / path.name) for path in sorted((ROOT / "results").glob("*.json"))]
    built = report.build(files, tmp_path / "figures", tmp_path, tmp_path / "docs" / "results")
    pages = ROOT / "docs" / "results"
    assert sorted(built.pages) == sorted(p.name for p in pages.glob("*.md") if p.name != "notes.md")
    for name, text in [("BENCHMARKS.md", built.summary), *((n, p.text) for n, p in built.pages.items())]:
        expected = _section(((pages / name) if name in built.pages else ROOT / name).read_text())
        if text != expected:
            got, want = text.splitlines(), expected.splitlines()
            line = next((i for i, (a, b) in enumerate(zip(got, want)) if a != b), min(len(got), len(want)))
            pytest.fail(f"{name} differs from what the results give from line {line + 1} of its section:\n"
                        f"  generated: {got[line] if line < len(got) else '(end)'}\n"
                        f"  committed: {want[line] if line < len(want) else '(end)'}")
    assert sorted(path.name for path in built.figures) == sorted(
        path.name for path in (ROOT / "figures").glob("*.png") if not path.name.startswith("keyframes-"))
    assert all(path.parent == tmp_path / "figures" for path in built.figures) and not (tmp_path / "figures").exists()


def _anchors(markdown: str) -> set[str]:
    """The anchors of `markdown`'s headings as GitHub (and the docs site's slugify) make them: lowercase, word
    characters, hyphens and spaces kept, spaces made hyphens (duplicates not numbered)."""
    import re

    heads = re.findall(r"^#{1,6} +(.+?) *$", re.sub(r"^```.*?^```", "", markdown, flags=re.M | re.S), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", h).lower()).replace(" ", "-")
            for h in heads}


def test_the_findings_and_the_pages_link_only_files_and_headings_that_exist():
    """Every relative link of BENCHMARKS.md and docs/results/*.md names a file of the repository, and a link into a
    markdown file (or the page itself) names one of its headings."""
    import re

    for page in [ROOT / "BENCHMARKS.md", *(ROOT / "docs" / "results").glob("*.md")]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            path, _, anchor = target.partition("#")
            if "://" in path:
                continue
            assert (page.parent / path).exists(), f"{page.relative_to(ROOT)} links {target}"
            if anchor:
                linked = (page.parent / path) if path else page
                assert anchor in _anchors(linked.read_text()), f"{page.relative_to(ROOT)} links {target}"


def test_a_sections_figure_is_drawn_once_only_with_a_figure_folder_and_linked_relative_to_the_page(tmp_path):
    from experiments.report.sections import Context, Section

    calls = []

    def draw():
        calls.append(1)
        return "a figure"

    assert Context({}, None, tmp_path).figure("x.png", "X", draw) == [] and calls == []
    ctx = Context({}, tmp_path / "out" / "figs", tmp_path / "out")
    assert ctx.figure("x.png", "X", draw) == ["![X](figs/x.png)", ""]
    assert ctx.on(tmp_path / "out" / "docs").figure("x.png", "X", draw) == ["![X](../figs/x.png)", ""]
    assert ctx.drawn == {tmp_path / "out" / "figs" / "x.png": "a figure"} and calls == [1]   # drawn once
    assert Section("T", "caption", ["table\n"]).lines() == ["## T", "", "caption", "", "table\n"]
    assert Section("", "note").lines(3) == ["note", ""]


def test_no_report_module_uses_another_modules_private_names():
    """What one module of `experiments.report` (or `experiments.compare`) takes from another is public: no
    `from experiments... import _name`, no `module._name`."""
    import ast

    paths = [*(ROOT / "experiments" / "report").rglob("*.py"), ROOT / "experiments" / "compare.py"]
    for path in paths:
        tree = ast.parse(path.read_text())
        ours = [node for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
                and (node.module or "").startswith("experiments")]
        modules = {a.asname or a.name for node in ours for a in node.names}
        private = [a.name for node in ours for a in node.names if a.name.startswith("_")]
        private += [f"{node.value.id}.{node.attr}" for node in ast.walk(tree) if isinstance(node, ast.Attribute)
                    and isinstance(node.value, ast.Name) and node.value.id in modules
                    and node.attr.startswith("_") and not node.attr.startswith("__")]
        assert not private, f"{path.relative_to(ROOT)} uses {private}"


def test_the_speed_sections_live_in_docs_speed_md():
    """`python -m experiments.bench_NAME --write docs/speed.md` replaces its section there, never appends one."""
    speed, benchmarks = (ROOT / "docs" / "speed.md").read_text(), (ROOT / "BENCHMARKS.md").read_text()
    for name in ("bench_envs", "bench_experts", "bench_train", "bench_images"):
        assert speed.count(f"<!-- {name}:start -->\n") == speed.count(f"<!-- {name}:end -->\n") == 1, name
        assert f"<!-- {name}:" not in benchmarks, name


def test_a_file_trained_again_shows_the_first_trainings_returns_beside_its_own(tmp_path):
    """A file written by `experiments.evaluate RUN --replaces FILE` carries the replaced file's record: the grid gains
    a "first training" column (the replaced summary, matched by configuration), `analysis.retrained_shift` says how
    far the means moved, and the provenance says why."""
    from experiments.report.analysis import retrained_shift

    first = _schema2(_results(methods=(("bc-so", {}, 300.0), ("bc-oh", {}, 1000.0))),
                     command=["python", "-m", "experiments.sweep", "--env", "hopper"])
    again = _schema2(_results(methods=(("bc-so", {}, 320.0), ("bc-oh", {}, 950.0),
                                       ("ours-step", {"thr": 0.1, "w": 5.0}, 990.0))),
                     command=["python", "-m", "experiments.sweep", "--env", "hopper", "--out", "runs/again"])
    again["replaces"] = {"file": "r.json", "command": first["command"], "system": {"commit": "f4e2e9a"},
                         "timing": first["timing"], "summary": first["summary"], "runs": []}
    text = report.report([_loaded(tmp_path, again)])
    assert "| return | % of expert | first training |" in text
    assert "| BC-SO | — | 2 | 320.0 ± 14.1 | 16.0 | 300.0 ± 14.1 |" in text   # ± the sample sd, both trainings
    assert "| BC-OH | — | 2 | 950.0 ± 14.1 | 47.5 | 1,000.0 ± 14.1 |" in text    # the new numbers are the table's
    assert "| **Ours (step)** | thr 0.1, w 5 | 2 | **990.0 ± 14.1** | 49.5 | — |" in text   # not in the first one
    # how far the means moved: BC-SO +20, BC-OH −50, each against a standard error of sqrt(2 · 14.1² / 2) = 14.1
    # (the sample sd of ∓ 10 over 2 seeds): 1.41 and 3.54 of them, median 2.47
    (m,) = report.merge([_loaded(tmp_path, again)]).values()
    assert retrained_shift(m) == pytest.approx((2, -50.0, 20.0, (20 + 50) / 2 / 200 ** 0.5, 1))
    assert ("Trained again: 2 configuration(s) moved by -50.0 to +20.0 in mean return, a median of 2.47 standard "
            "errors; 1 of 2 by more than two.") in text
    line = report.provenance(Results.from_json(again))
    assert "trained again with its policies kept, to replace the file of commit `f4e2e9a`" in line
    assert "that file's command `python -m experiments.sweep --env hopper`" in line
    assert "first training" not in report.report([_loaded(tmp_path, first, "f.json")])  # only where a file replaced
    (m,) = report.merge([_loaded(tmp_path, first, "f.json")]).values()
    assert retrained_shift(m) is None
    bad = {**again, "replaces": {"summary": [{"method": "bc-oh"}]}}
    with pytest.raises(report.ReportError, match="replaces.summary"):
        _loaded(tmp_path, bad, "bad.json")


# -- reports of one and two seeds ----------------------------------------------------------------------------------

def _few_seeds(tmp_path, deltas):
    """`_results` over `deltas` seeds as the sweep writes them: one seed records no std (None)."""
    obj = _results(deltas=deltas)
    if len(deltas) == 1:
        for row in obj["summary"]:
            row["return_std"] = row["normalized_std"] = None
    return _loaded(tmp_path, obj)


def test_a_one_seed_report_shows_no_sd_no_interval_and_no_best(tmp_path):
    built = report.build([_few_seeds(tmp_path, (0.0,))])
    page, index = built.pages["hopper-pos.md"].text, built.pages["index.md"].text
    for text in (page, index):
        assert "nan" not in text and "**" not in text, text   # no "± nan", no bolded best
    assert "| Ours (step) | thr 0.2, w 3 | 1 | 1,600.0 | 80.0 |" in page   # the grid's highest mean, not bold
    assert "not judged at 1 seed" in page and "within one std" not in page
    difference = next(line for line in index.splitlines() if "| BC-OH − BC-SO" in line)
    assert "| 1 / 1 | +700 (return) | — | no verdict" in difference   # no [+700, +700]


def test_a_two_seed_report_marks_its_intervals_wide(tmp_path):
    built = report.build([_few_seeds(tmp_path, (-10.0, 10.0))])
    page, index = built.pages["hopper-pos.md"].text, built.pages["index.md"].text
    difference = next(line for line in index.splitlines() if "| BC-OH − BC-SO" in line)
    assert "| 2 / 2 |" in difference and "] (2 seeds: wide) |" in difference
    assert "within one std" in page and "**Ours (step)**" in page   # two seeds: a std, and a best by its mean


def test_interval_cells_by_seeds():
    from experiments.report.analysis import Interval, RecipeCell
    from experiments.report.sections.common import diff_cell, interval, pct_cell, seeds_cell

    assert interval(1.0, 2.0, 1) == "" and interval(1.0, 2.0, 3) == "[1.0, 2.0]"
    assert interval(1.0, 2.0, 2) == "[1.0, 2.0] (2 seeds: wide)" and interval(1.0, 2.0, 2, note=False) == "[1.0, 2.0]"
    assert pct_cell(RecipeCell(50.0, 50.0, 50.0, (50.0,))) == "50.0"
    assert pct_cell(RecipeCell(50.0, 40.0, 60.0, (45.0, 50.0, 55.0))) == "50.0 [40.0, 60.0]"
    assert diff_cell(Interval(5.0, 5.0, 5.0, 1, 4)) == "+5.0"
    assert diff_cell(Interval(5.0, 1.0, 9.0, 2, 2)) == "**+5.0 [+1.0, +9.0] (2 seeds: wide)**"
    assert (seeds_cell(1), seeds_cell(2), seeds_cell(5)) == ("1", "2 (intervals wide)", "5")
