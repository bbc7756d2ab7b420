"""Copycat diagnostics (`ape_jax.diagnostics`, each run's `diagnostics`) in the sweep's printed table and in the report.

The fixtures are committed results files with synthetic `diagnostics` blocks added: BC-OH copycat in 2 of 5 seeds,
BC-SO with one seed the diagnostics could not read (`{"absent": …}`) and one null embedding ratio, Ours with no
seed read. Files without diagnostics must print and report exactly as before.
"""

import difflib
import json
import pathlib

import numpy as np
import pytest

from ape_jax.pipeline import results
from experiments import report
from experiments.report.analysis import Spread, diagnostics_rows, policy_diagnostics, spread
from experiments.report.sections.diagnostics import thresholds_line
from experiments.sweep import table

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
FCA_BC = RESULTS / "hopper-pos-fca-rows-default-fca-bc.json"   # recipe fca: BC-SO, BC-OH, Ours (10% × 5), 5 seeds
MLP_BC = RESULTS / "hopper-pos-fca-rows-default-mlp-bc.json"   # the same under recipe mlp
NO_EMBEDDING = "the policy network has no embedding"


def _block(emb, pred, vel=0.1):
    """A readable diagnostics block with the verdict `ape_jax.diagnostics.verdict` gives at the 0.5 thresholds."""
    return {"embedding_ratio": emb, "prev_from_embedding": None if emb is None else 0.01 * emb,
            "prev_from_action": 0.01, "velocity_ratio": vel, "predictability_ratio": pred,
            "policy_mse": 0.002 * pred, "expert_mse": 0.002, "predictability_steps": 4000,
            "verdict": "copycat" if emb is not None and emb <= 0.5 and pred <= 0.5 else "not copycat"}


DIAGNOSTICS = {  # per method, per seed 0..4
    "bc-oh": [_block(0.1, 0.3), _block(0.2, 0.2), _block(0.6, 0.4), _block(0.8, 0.9), _block(0.9, 1.1)],
    "bc-so": [{"absent": NO_EMBEDDING}, _block(None, 0.7, None), _block(0.95, 1.0, None), _block(1.1, 0.8, None),
              _block(1.0, 1.2, None)],
    "ours-step": [{"absent": NO_EMBEDDING}] * 5,
}
CONFIG = {"thresholds": {"embedding_ratio": 0.5, "predictability_ratio": 0.5}, "probe_steps": 2000,
          "probe_rows": {"train": 10_000, "val": 2_000}, "expert_rollouts": "the validation episodes",
          "velocity": "qvel"}


def _plain(path: pathlib.Path) -> dict:
    """A committed results file as parsed JSON, without diagnostics (the committed files have none yet)."""
    obj = json.loads(path.read_text())
    for run in obj["runs"]:
        run.pop("diagnostics", None)
    obj["config"].pop("diagnostics", None)
    return obj


def _diagnosed(path: pathlib.Path) -> dict:
    obj = _plain(path)
    for run in obj["runs"]:
        run["diagnostics"] = DIAGNOSTICS[run["method"]][run["seed"]]
    obj["config"]["diagnostics"] = CONFIG
    return obj


def _loaded(tmp_path, obj, name):
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return report.load(path)


def _pct_of_expert(obj, method) -> str:
    return f"{np.mean([r['eval']['normalized'] for r in obj['runs'] if r['method'] == method]):.1f}"


def test_a_ratio_spread_skips_null_and_non_finite_seeds_and_absent_seeds_are_not_counted():
    assert spread([None, 0.2, float("nan"), 0.4, float("inf")]) == Spread(pytest.approx(0.3), 0.2, 0.4, 2)
    assert spread([None, None]) is None
    runs = [{"status": "ok", "diagnostics": d} for d in DIAGNOSTICS["bc-so"]] + \
        [{"status": "failed", "diagnostics": _block(0.1, 0.1)}]                  # a failed run is no seed
    d = policy_diagnostics(runs)
    assert (d.read, d.copycats, d.absent) == (4, 0, ((NO_EMBEDDING, 1),))
    assert d.embedding == Spread(1.0, 0.95, 1.1, 3) and d.velocity is None      # null, not 0, is left out
    assert d.predictability.n == 4 and d.predictability.median == pytest.approx(0.9)
    assert policy_diagnostics([{"status": "ok", "diagnostics": d} for d in DIAGNOSTICS["bc-oh"]]).copycats == 2


def test_the_printed_table_appends_median_ratios_and_the_copycat_count():
    plain = table(results.Results.from_json(_plain(FCA_BC))).splitlines()
    lines = table(results.Results.from_json(_diagnosed(FCA_BC))).splitlines()
    assert lines[0] == plain[0] + "  emb ratio  pred ratio  copycat"
    rows = {line[2:].split()[0]: line for line in lines[1:4]}
    assert rows["bc-oh"].split()[-3:] == ["0.6", "0.4", "2/5"]    # medians over 5 seeds; 2 judged copycat
    assert rows["bc-so"].split()[-3:] == ["1", "0.9", "0/4"]      # null ratio left out (with it as 0: 0.975)
    assert rows["ours-step"].split()[-3:] == ["-", "-", "-"]      # no seed read: "-", never 0
    for old, new in zip(plain[1:4], lines[1:4]):                  # the existing columns as they were
        assert new.startswith(old) and len(new) == len(old) + 2 + 9 + 2 + 10 + 2 + 7
    assert lines[4] == plain[4]                                    # the expert line
    assert lines[5] == ("copycat = embedding ratio <= 0.5 and predictability ratio <= 0.5 (both, per seed; fixed "
                        "before any result)")
    assert f"no copycat diagnostics: bc-so, 1 of 5 seeds: {NO_EMBEDDING}" in lines
    assert f"no copycat diagnostics: ours-step thr=0.1, w=5, 5 of 5 seeds: {NO_EMBEDDING}" in lines


def test_a_file_without_readable_diagnostics_prints_as_before():
    plain = table(results.Results.from_json(_plain(FCA_BC)))
    assert "emb ratio" not in plain and "copycat =" not in plain and len(plain.splitlines()) == 5
    absent = _plain(FCA_BC)
    for run in absent["runs"]:   # every policy unreadable: nothing to tabulate, so no columns of dashes
        run["diagnostics"] = {"absent": NO_EMBEDDING}
    assert table(results.Results.from_json(absent)) == plain


def test_the_report_tabulates_each_configurations_diagnostics_and_states_the_thresholds_once(tmp_path):
    fca, mlp = _diagnosed(FCA_BC), _plain(MLP_BC)
    built = report.build([_loaded(tmp_path, fca, "fca.json"), _loaded(tmp_path, mlp, "mlp.json")])
    text = built.pages["index.md"].text
    rule = ("Copycat = embedding ratio ≤ 0.5 and predictability ratio ≤ 0.5, both, per seed (thresholds fixed "
            "before any result, `ape_jax.diagnostics.THRESHOLDS`).")
    # the recipe section: one table of task × recipe × configuration, only the recipe whose file has diagnostics
    recipe = text[text.index("## The paper's recipe"):]
    recipe = recipe[:recipe.index("\n## ")]
    assert (f"| Hopper | bn-mlp | BC-OH | — | 5 | {_pct_of_expert(fca, 'bc-oh')} | 0.6 (0.1–0.9) | 0.1 | "
            "0.4 (0.2–1.1) | copycat 2/5 (first verdict only) |") in recipe
    assert (f"| Hopper | bn-mlp | BC-SO | — | 5 | {_pct_of_expert(fca, 'bc-so')} | 1 (0.95–1.1) | — | "
            "0.9 (0.7–1.2) | copycat 0/4 (first verdict only) |") in recipe
    assert (f"| Hopper | bn-mlp | Ours (step) | thr 0.1, w 5 | 5 | {_pct_of_expert(fca, 'ours-step')} | "
            "— | — | — | — |") in recipe
    assert "| Hopper | mlp |" not in recipe and recipe.count(rule) == 1
    assert f"- Ours (step) (Hopper, recipe bn-mlp, thr 0.1, w 5): no diagnostics for 5 of 5 seeds: {NO_EMBEDDING}" \
        in recipe
    # each group's section of its task's page: the group's own table, its columns explained in the notes
    sections = built.pages["hopper-pos.md"].text.split("\n## ")
    fca_group = next(s for s in sections if s.startswith("Protocol mujoco-state, split by rows, recipe bn-mlp\n"))
    mlp_group = next(s for s in sections if s.startswith("Protocol mujoco-state, split by rows, recipe mlp\n"))
    assert "| method | hparams | seeds | % of expert | embedding ratio | velocity 1 − R² | predictability ratio | " \
           "verdict |" in fca_group
    assert (f"| BC-OH | — | 5 | {_pct_of_expert(fca, 'bc-oh')} | 0.6 (0.1–0.9) | 0.1 | 0.4 (0.2–1.1) | "
            "copycat 2/5 (first verdict only) |") in fca_group
    assert fca_group.count(rule) == 1 and "(columns explained in [the notes](notes.md#the-copycat-diagnostics))" \
        in fca_group
    assert f"- BC-SO: no diagnostics for 1 of 5 seeds: {NO_EMBEDDING}" in fca_group
    assert "embedding ratio" not in mlp_group and "Copycat diagnostics" not in mlp_group


def test_the_report_of_files_without_diagnostics_is_the_same_and_diagnostics_only_add_lines(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    plain = [_loaded(tmp_path / "a", _plain(p), p.name) for p in (FCA_BC, MLP_BC)]
    text = report.build(plain, base=tmp_path / "a").text
    assert "embedding ratio" not in text and "Copycat diagnostics" not in text
    assert all(not diagnostics_rows(m) for m in report.merge(plain).values())
    diagnosed = report.build([_loaded(tmp_path / "b", _diagnosed(FCA_BC), FCA_BC.name),
                              _loaded(tmp_path / "b", _plain(MLP_BC), MLP_BC.name)], base=tmp_path / "b").text
    ops = difflib.SequenceMatcher(None, text.splitlines(), diagnosed.splitlines(), autojunk=False).get_opcodes()
    assert {op for op, *_ in ops} == {"equal", "insert"}               # nothing of the old report changed


def test_the_thresholds_line_says_what_the_files_record():
    assert thresholds_line([]) == ("Copycat = both ratios at or below their thresholds, per seed; the files record "
                                   "no thresholds.")
    two = thresholds_line([{"embedding_ratio": 0.5, "predictability_ratio": 0.5},
                           {"embedding_ratio": 0.4, "predictability_ratio": 0.5}])
    assert "the files record different ones: embedding ratio ≤ 0.5 and predictability ratio ≤ 0.5; embedding " \
           "ratio ≤ 0.4 and predictability ratio ≤ 0.5." in two


def test_runs_evaluated_during_training_get_a_table_per_iteration_with_intervals_and_diagnostics(tmp_path):
    """`budget.eval_at`: each run's `at` list; the report shows every configuration at each point and at the end."""
    obj = _diagnosed(FCA_BC)
    obj["config"]["iterations"] = 30_000
    for run in obj["runs"]:
        run["at"] = [{"iteration": 10_000, "eval": {**run["eval"], "normalized": 10.0 + run["seed"]},
                      "train_loss": 0.02, "diagnostics": _block(0.3, 0.3)}]
    text = report.build([_loaded(tmp_path, obj, "fca.json")]).text
    section = text[text.index("The same policies over training"):]
    # at 10k: seeds 10..14 % of expert, mean 12 with its bootstrap interval; every seed copycat there
    at_10k = next(line for line in section.splitlines() if line.startswith("| BC-OH | — | 10,000 |"))
    assert at_10k.startswith("| BC-OH | — | 10,000 | 12.0 [") and at_10k.endswith(
        "| 0.02 | 0.3 (0.3–0.3) | 0.3 (0.3–0.3) | copycat 5/5 (first verdict only) |")
    at_end = next(line for line in section.splitlines() if line.startswith("| BC-OH | — | 30,000 |"))
    assert at_end.startswith(f"| BC-OH | — | 30,000 | {_pct_of_expert(obj, 'bc-oh')} [")
    assert at_end.endswith("| 0.6 (0.1–0.9) | 0.4 (0.2–1.1) | copycat 2/5 (first verdict only) |")
    assert "The same policies over training" not in report.build([_loaded(tmp_path, _diagnosed(FCA_BC), "b.json")]).text


def _judged(path: pathlib.Path) -> dict:
    """`_diagnosed` judged against its BC-SO (`ape_jax.pipeline.judge`), with BC-OH's errors made small: seeds 0 and
    1 hold a_{t−1} 5× better than BC-SO (control ratio 0.2) and are smooth, so the controlled verdict calls them
    copycats; the first verdict's count (2/5, from the recorded `verdict`) stays as it was."""
    from ape_jax.pipeline import judge

    obj = _diagnosed(path)
    for run in obj["runs"]:
        d = run["diagnostics"]
        if run["method"] == "bc-so" and "absent" not in d:
            d["prev_from_embedding"] = 0.01
        if run["method"] == "bc-oh":
            d["prev_from_embedding"] = 0.002 if run["seed"] < 2 else 0.008
    return judge.judge(results.Results.from_json(obj)).to_json()


def test_the_report_shows_the_controlled_verdict_with_the_first_beside_it(tmp_path):
    fca = _judged(FCA_BC)
    bc_oh = [r["diagnostics"] for r in fca["runs"] if r["method"] == "bc-oh"]
    assert [d["controlled_verdict"] for d in bc_oh] == ["copycat"] * 2 + ["not copycat"] * 3
    text = report.build([_loaded(tmp_path, fca, "fca.json"), _loaded(tmp_path, _plain(MLP_BC), "mlp.json")]).text
    recipe = text[text.index("## The paper's recipe"):]
    recipe = recipe[:recipe.index("\n## ")]
    assert ("| task | recipe | method | hparams | seeds | % of expert | embedding ratio | control ratio | "
            "velocity 1 − R² | predictability ratio | verdict |") in recipe
    assert (f"| Hopper | bn-mlp | BC-OH | — | 5 | {_pct_of_expert(fca, 'bc-oh')} | 0.6 (0.1–0.9) | 0.8 (0.2–0.8) | "
            "0.1 | 0.4 (0.2–1.1) | copycat 2/5 (first verdict 2/5) |") in recipe
    # BC-SO against the median of its own seeds: 1 by construction; never a copycat
    assert (f"| Hopper | bn-mlp | BC-SO | — | 5 | {_pct_of_expert(fca, 'bc-so')} | 1 (0.95–1.1) | 1 (1–1) | — | "
            "0.9 (0.7–1.2) | copycat 0/4 (first verdict 0/4) |") in recipe
    assert ("Copycat (the controlled verdict) = a policy that sees a past (a history of more than one observation, "
            "or the previous action in view) with control ratio ≤ 0.25 and predictability ratio ≤ 0.5, both, per "
            "seed; a policy without a past never is. The first verdict, beside it: embedding ratio ≤ 0.5 and "
            "predictability ratio ≤ 0.5, both, per seed") in recipe


def test_the_printed_table_adds_the_control_ratio_and_the_controlled_count():
    lines = table(results.Results.from_json(_judged(FCA_BC))).splitlines()
    assert lines[0].endswith("  emb ratio  pred ratio  copycat  ctl ratio  controlled")
    rows = {line[2:].split()[0]: line for line in lines[1:4]}
    assert rows["bc-oh"].split()[-5:] == ["0.6", "0.4", "2/5", "0.8", "2/5"]
    assert rows["bc-so"].split()[-5:] == ["1", "0.9", "0/4", "1", "0/4"]
    assert lines[7].startswith("controlled = a policy that sees a past with ctl ratio <= 0.25 and pred ratio <= 0.5")
