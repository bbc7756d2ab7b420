"""The paper's budget in the report (`analysis.paper_budget_groups`, `budget_rows`,
`sections.recipe.paper_budget_section`) and the extended copycat map (`analysis.extended_map`,
`sections.copycat.extended_map_section`).

The fixture is the committed recipe-fca file (BC-SO, BC-OH, Ours 10% × 5 at 30k, 5 seeds) turned into a `paper`-preset
file of 300k iterations whose runs were also evaluated at 30k and 100k (`at`), with numbers and diagnostics chosen
so each point differs: BC-OH is copycat in every seed at 300k and in none before.
"""

import json
import pathlib

import numpy as np
import pytest

from experiments import report
from experiments.report.analysis import (Key, budget_differences, budget_rows, cell_title, mean_difference,
                                         extended_map, paper_budget_groups, regime_budget_groups)

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
FCA_BC = RESULTS / "hopper-pos-fca-rows-default-fca-bc.json"   # recipe fca: BC-SO, BC-OH, Ours (10% × 5), 5 seeds
SHIFT = {30_000: -20.0, 100_000: -10.0}                         # % of expert at each point: the end's + SHIFT
COPYCAT = {"embedding_ratio": 0.2, "prev_from_embedding": 0.002, "prev_from_action": 0.01, "velocity_ratio": 0.5,
           "predictability_ratio": 0.3, "policy_mse": 0.0006, "expert_mse": 0.002, "predictability_steps": 4000,
           "verdict": "copycat"}
HONEST = {**COPYCAT, "embedding_ratio": 1.5, "prev_from_embedding": 0.015, "predictability_ratio": 1.2,
          "policy_mse": 0.0024, "verdict": "not copycat"}


def _paper_file(tmp_path):
    obj = json.loads(FCA_BC.read_text())
    obj["preset"], obj["config"]["iterations"] = "paper", 300_000
    for run in obj["runs"]:
        run["diagnostics"] = COPYCAT if run["method"] == "bc-oh" else HONEST
        run["at"] = [{"iteration": i, "train_loss": 0.01,
                      "eval": {**run["eval"], "normalized": run["eval"]["normalized"] + shift,
                               "return_mean": run["eval"]["return_mean"] + 10 * shift},
                      "diagnostics": HONEST} for i, shift in SHIFT.items()]
    path = tmp_path / "paper.json"
    path.write_text(json.dumps(obj))
    return report.load(path)


def _normalized(method: str) -> list[float]:
    runs = [r for r in json.loads(FCA_BC.read_text())["runs"] if r["method"] == method]
    return [r["eval"]["normalized"] for r in sorted(runs, key=lambda r: r["seed"])]


def test_a_paper_preset_file_is_a_group_of_its_own_beside_the_default_one(tmp_path):
    merged = report.merge([_paper_file(tmp_path), report.load(FCA_BC)])   # the same configurations: never merged
    assert set(merged) == {Key("hopper", "pos", "mujoco-state.rows.bn-mlp"),
                           Key("hopper", "pos", "mujoco-state.rows.bn-mlp", 300_000)}
    assert [m.budget for m in paper_budget_groups(merged)] == [300_000]


def test_budget_rows_hold_every_point_with_table5_beside_its_methods(tmp_path):
    (m,) = paper_budget_groups(report.merge([_paper_file(tmp_path)]))
    rows = {r.method: r for r in budget_rows(m)}
    assert set(rows) == {"bc-so", "bc-oh", "ours-step"}        # the softmax and FCA did not run: no rows
    assert {k: r.paper for k, r in rows.items()} == {"bc-so": 275, "bc-oh": 293, "ours-step": 641}
    bcoh = rows["bc-oh"]
    assert [p.iteration for p in bcoh.points] == [30_000, 100_000, 300_000]
    end = np.mean(_normalized("bc-oh"))
    assert [p.normalized.mean for p in bcoh.points] == pytest.approx([end - 20, end - 10, end])
    assert [(p.diagnostics.copycats, p.diagnostics.read) for p in bcoh.points] == [(0, 5), (0, 5), (5, 5)]
    (lab, history), *others = budget_differences(list(rows.values()))
    assert lab == "BC-OH − BC-SO" and history[300_000] == mean_difference(_normalized("bc-oh"),
                                                                               _normalized("bc-so"))
    assert history[30_000].diff == pytest.approx(history[300_000].diff)   # both shifted alike
    assert [o[0] for o in others] == ["Ours, step THR 10% W 5 − BC-OH"]


def test_the_report_shows_the_paper_budget_table_beside_table5_with_differences_and_diagnostics(tmp_path):
    built = report.build([_paper_file(tmp_path), report.load(FCA_BC)], figure_dir=tmp_path / "figures")
    text, drawn = built.pages["index.md"].text, built.figures
    section = text[text.index("## The paper's budget with the paper's recipe"):]
    section = section[:section.index("\n## ")]
    end = np.mean(_normalized("bc-oh"))
    row = next(line for line in section.splitlines() if line.startswith("| Hopper | BC-OH | 5 | "))
    assert row.startswith(f"| Hopper | BC-OH | 5 | {end - 20:.1f} [") and f"| {end:.1f} [" in row
    assert row.endswith("| 1.00× | 293 | 1.00× |")
    assert next(line for line in section.splitlines()
                if line.startswith("| Hopper | BC-SO |")).endswith(f"| 275 | {275 / 293:.2f}× |")
    assert "| Hopper | BC-OH − BC-SO | " in section and "| Hopper | Ours, step THR 10% W 5 − BC-OH | " in section
    assert "| Hopper | BC-OH | 1.5 → 1.5 → 0.2 | 1.2 → 1.2 → 0.3 | 0/5 (first verdict only) → 0/5 (first verdict " \
        "only) → 5/5 (first verdict only) |" in section
    assert "### Table 5 at the paper's budget" in built.summary and row in built.summary   # the findings' block too
    assert {p.name for p in drawn} >= {"paper-budget.png", "copycat-map-training.png"}   # the map along training


def test_the_extended_map_has_the_budget_axis_and_names_where_copycat_was_judged(tmp_path):
    files = [_paper_file(tmp_path), report.load(FCA_BC)]
    points = [q for q in extended_map(report.merge(files)) if q.setting == "recipe bn-mlp, split by rows"]
    assert [(q.run, q.iteration) for q in points] == [(30_000, 30_000), (300_000, 30_000), (300_000, 100_000),
                                                      (300_000, 300_000)]
    assert [q.diagnostics.copycats for q in points] == [0, 0, 0, 5]   # the committed file: read, none copycat
    # the committed file's cell has the controlled verdict (none copycat); the fixture's, the first verdict only
    assert [(q.diagnostics.judged, q.diagnostics.controlled) for q in points] == [(5, 0), (0, 0), (0, 0), (0, 0)]
    text = report.build(files).pages["index.md"].text
    section = text[text.index("## Where copycat appears: the map, extended"):]
    assert "| Hopper | bn-mlp, rows | 1 | 20,000 | 300k | 100k | " in section
    assert "| Hopper | bn-mlp, rows | 1 | 20,000 | 300k | 300k | " in section
    assert "| 5/5 (first verdict only) |" in section


def test_a_longer_history_is_a_setting_of_its_own_in_the_map_and_stays_out_of_the_recipe_table(tmp_path):
    obj = json.loads(FCA_BC.read_text())
    obj["protocol"]["history"] = obj["settings"]["protocol"]["history"] = 7   # `--set protocol.history=7`
    path = tmp_path / "h7.json"
    path.write_text(json.dumps(obj))
    files = [report.load(path), report.load(FCA_BC), report.load(RESULTS / "hopper-pos-fca-rows-default-mlp-bc.json")]
    merged = report.merge(files)   # the same configurations as the history-2 file: a group of its own, not merged
    assert Key("hopper", "pos", "mujoco-state.rows.bn-mlp.h7") in merged
    settings = [q.setting for q in extended_map(merged)]
    assert settings == ["recipe mlp, split by rows", "recipe bn-mlp, split by rows",
                        "recipe bn-mlp, split by rows, history 7"]
    built = report.build(files)
    text = built.pages["index.md"].text
    recipe = text[text.index("## The paper's recipe"):]
    recipe = recipe[:recipe.index("\n## ")]
    assert "history 7" not in recipe   # the recipe table compares mlp with fca at the protocol's own history
    assert "| Hopper | bn-mlp, rows, history 7 | 1 | 20,000 | 30k | 30k | " in text
    assert "## Protocol mujoco-state, split by rows, recipe bn-mlp, history 7\n" in built.pages["hopper-pos.md"].text


def test_another_expert_is_a_setting_of_its_own(tmp_path):
    obj = json.loads(FCA_BC.read_text())
    obj["protocol"]["expert"] = obj["settings"]["protocol"]["expert"] = "ppo"   # `--set protocol.expert=ppo`
    path = tmp_path / "ppo.json"
    path.write_text(json.dumps(obj))
    merged = report.merge([report.load(path), report.load(FCA_BC)])
    assert Key("hopper", "pos", "mujoco-state.rows.bn-mlp.ppo") in merged
    assert [q.setting for q in extended_map(merged)] == ["recipe bn-mlp, split by rows",
                                                         "recipe bn-mlp, split by rows, expert ppo"]
    assert "| Hopper | bn-mlp, rows, expert ppo | 1 | 20,000 | 30k | 30k | " in report.build([report.load(path)]).text


def _with_iterations(tmp_path, name: str, preset: str, iterations: int, recorded: int | None):
    obj = json.loads(FCA_BC.read_text())
    obj["preset"], obj["config"]["iterations"] = preset, iterations
    if recorded is not None:
        obj["config"]["preset_iterations"] = recorded
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(obj))
    return report.load(path)


def test_a_files_budget_label_comes_from_what_it_records_not_from_todays_presets(tmp_path):
    from experiments.report.analysis import budget_of

    # its preset gave 12,345 when it ran (today's default gives 30k): it trained its preset's budget
    assert budget_of(_with_iterations(tmp_path, "a", "default", 12_345, 12_345)) is None
    # its iterations were overridden: a budget of its own, whatever today's preset says
    assert budget_of(_with_iterations(tmp_path, "b", "default", 30_000, 12_345)) == 30_000
    # a file from before the record is compared with today's preset of its name
    assert budget_of(_with_iterations(tmp_path, "c", "default", 30_000, None)) is None
    assert budget_of(_with_iterations(tmp_path, "d", "default", 12_345, None)) == 12_345
    # a paper run is the default experiment trained longer: its own group always, but the paper-budget table
    # takes only those that trained the paper preset's iterations
    short = _with_iterations(tmp_path, "e", "paper", 100_000, 300_000)
    assert budget_of(short) == 100_000 and not paper_budget_groups(report.merge([short]))


def test_the_sweep_records_the_iterations_its_preset_gave_before_overrides():
    from ape_jax.pipeline.presets import resolve

    base = resolve("hopper", "pos", preset="default")
    over = resolve("hopper", "pos", preset="default", sets=["budget.iterations=777"])
    assert over.budget.iterations == 777 and over.preset_iterations == base.budget.iterations == base.preset_iterations


FCA_EXPERT_300K = RESULTS / "hopper-pos-mujoco-state-rows-paper-bn-mlp-cs294-raw-seeds0.json"   # 2 seeds


def test_table5_with_fcas_expert_at_the_papers_budget_reads_beside_the_shipped_experts(tmp_path):
    """The 300k run with FCA's imported expert (raw labels) is a row block of the paper-budget table, named by its
    setting, with PALR's row and every point it was evaluated at; the shipped experts' blocks keep their titles."""
    files = [report.load(FCA_EXPERT_300K), _paper_file(tmp_path)]
    merged = report.merge(files)
    assert [m.budget for m in paper_budget_groups(merged)] == [300_000]          # the shipped expert's only
    (m,) = regime_budget_groups(merged)
    rows = {r.method: r for r in budget_rows(m, cell_title(m))}
    assert list(rows) == ["bc-so", "bc-oh", "ours-step", "fca", "palr"]
    assert {r.task for r in rows.values()} == {"Hopper (FCA's expert, raw labels)"}
    assert [p.iteration for p in rows["palr"].points] == [30_000, 100_000, 300_000]
    runs = json.loads(FCA_EXPERT_300K.read_text())["runs"]
    palr = [r["eval"]["normalized"] for r in runs if r["method"] == "palr"]
    assert rows["palr"].at(300_000).normalized.mean == pytest.approx(np.mean(palr))
    assert rows["palr"].paper is None and rows["bc-oh"].paper == 293
    bcoh = [r for r in runs if r["method"] == "bc-oh"]   # the validation loss at every point, the end's from the run
    assert rows["bc-oh"].at(30_000).val_loss.median == pytest.approx(
        np.median([a["losses"]["val"]["unweighted"] for r in bcoh for a in r["at"] if a["iteration"] == 30_000]))
    assert rows["bc-oh"].at(300_000).val_loss.median == pytest.approx(
        np.median([r["losses"]["val"]["unweighted"] for r in bcoh]))

    text = report.build(files, figure_dir=tmp_path / "figures").text
    table5 = text[text.index("### Table 5 at the paper's budget"):]
    lines = [line for line in table5[:table5.index("\n### ")].splitlines() if line.startswith("| ")]
    assert any(line.startswith("| Hopper | BC-OH | 5 | ") for line in lines)
    assert any(line.startswith("| Hopper (FCA's expert, raw labels) | PALR | 2 | ") for line in lines)
    assert any(line.startswith("| Hopper (FCA's expert, raw labels) | PALR − BC-OH | ") for line in lines)
