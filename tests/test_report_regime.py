"""Table 5 with FCA's expert in the report: files of an imported expert or raw labels form groups of their own (by
the expert's name and SHA-256, and by labels), the section's numbers on a hand-checkable case, and files without
expert references refused by the report and by `experiments.compare`.

The fixtures are synthetic results files of the expert-regime sweeps' shape (`results/queue/expert-regime.sh`):
Hopper, protocol fca split by rows, recipe fca, an imported expert recorded as `experiments.import_expert` records
it (a made-up SHA-256 and origin: no real expert file is read)."""


import numpy as np
import pytest

from experiments import compare, report
from experiments.report.analysis import Key, check_references, expert_words, merge, regime_groups, regime_table
from test_report import _fca, _results, _schema2, _write

SHA = "ab12" * 16
OTHER_SHA = "cd34" * 16
ORIGIN = "https://example.org/fca (data/experts/Hopper-v1.pkl)"


def imported(sha=SHA):
    """A demonstrator record as collection writes it for an imported expert (`collect.expert_for`)."""
    return {"kind": "imported", "name": "hopper-fca", "variant": "fca", "format": "cs294-pickle", "sha256": sha,
            "origin": ORIGIN, "network": {"action_size": 3, "activation": "tanh", "head": "linear",
                                          "hidden": [64, 64], "obs_size": 11}}


SHIPPED = {"kind": "checkpoint", "path": "envs/experts/hopper-rough", "card_sha256": "ef" * 32,
           "algorithm": "rough PPO", "return_mean": 900.0, "return_std": 5.0, "random_return_mean": 10.0}

# Returns per configuration; the fixture's expert returns 2,000 and a random policy 0, so % of expert = return / 20
# and each seed is the return + (-10, 0, +10): BC-SO 20%, BC-OH 30%, Ours (step) 50%, Ours (softmax) 30%, FCA α 0.1
# 15%, FCA α 2 35%, BC-full 70%.
METHODS = (("bc-so", {}, 400.0), ("bc-oh", {}, 600.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 1000.0),
           ("ours-softmax", {"tau": 0.2}, 600.0), ("fca", {"alpha": 0.1, "adversary_lr": 4e-4}, 300.0),
           ("fca", {"alpha": 2.0, "adversary_lr": 4e-4}, 700.0), ("bc-full", {}, 1400.0))
DIAGNOSTICS = {"embedding_ratio": 0.4, "prev_from_embedding": 0.002, "prev_from_action": 0.01, "velocity_ratio": 0.5,
               "predictability_ratio": 0.3, "policy_mse": 0.0006, "expert_mse": 0.002, "predictability_steps": 4000,
               "verdict": "copycat", "control_ratio": 0.2, "controlled_verdict": "copycat"}
# BC-OH's three seeds: copycat by the controlled verdict in two (control ratio ≤ 0.25), by the first in all three
BCOH_SEEDS = ({"control_ratio": 0.2, "predictability_ratio": 0.3},
              {"control_ratio": 0.22, "predictability_ratio": 0.35},
              {"control_ratio": 0.4, "predictability_ratio": 0.6, "controlled_verdict": "not copycat"})
HONEST = {**DIAGNOSTICS, "embedding_ratio": 1.5, "predictability_ratio": 1.2, "control_ratio": 1.0,
          "verdict": "not copycat", "controlled_verdict": "not copycat"}


def regime_file(labels="raw", expert="fca", found=None, methods=METHODS, references=True):
    """A schema-3 results file of the expert-regime sweeps' shape: Hopper, fca protocol split by rows, recipe fca,
    demonstrations by `found` (default: an imported expert) with `labels`; 3 seeds; BC-OH's diagnostics as in
    `BCOH_SEEDS`, every other policy's honest."""
    protocol = {**_fca(1), "split": "rows", **({"expert": expert} if expert else {}),
                **({"labels": labels} if labels != "clipped" else {})}
    obj = _schema2(_results("hopper", methods, deltas=(-10.0, 0.0, 10.0)), protocol=protocol,
                   command=["python", "-m", "experiments.sweep", "--protocol", "mujoco-state", "--recipe", "bn-mlp"])
    obj["schema"] = 3
    obj["settings"] = {"protocol": dict(protocol), "budget": {"iterations": 30000, "seeds": 3},
                       "recipe": {"name": "fca"}}
    obj["config"]["data"] = {"settings": {"expert": imported() if found is None else found,
                                          **({"labels": labels} if labels != "clipped" else {})}}
    obj["config"]["diagnostics"] = {"thresholds": {"embedding_ratio": 0.5, "predictability_ratio": 0.5,
                                                   "control_ratio": 0.25}}
    for run in obj["runs"]:
        run["diagnostics"] = ({**DIAGNOSTICS, **BCOH_SEEDS[run["seed"]]} if run["method"] == "bc-oh" else HONEST)
    if not references:
        obj["expert"] = {"return_mean": None, "return_std": None, "random_return_mean": None, "kind": "shipped"}
        for run in obj["runs"]:
            run["eval"].pop("normalized")
        for row in obj["summary"]:
            row["normalized_mean"] = row["normalized_std"] = None
    return obj


def _load(tmp_path, obj, name):
    return report.load(_write(tmp_path, name, obj))


def test_an_imported_expert_and_its_labels_make_groups_of_their_own(tmp_path):
    files = [_load(tmp_path, regime_file("raw"), "raw.json"), _load(tmp_path, regime_file("clipped"), "clipped.json"),
             _load(tmp_path, regime_file("raw", found=imported(OTHER_SHA)), "other.json"),
             _load(tmp_path, regime_file("clipped", expert=None, found={"kind": "checkpoint"}), "sac.json"),
             _load(tmp_path, regime_file("raw", expert="rough", found=SHIPPED), "rough.json")]
    merged = merge(files)   # the same configurations in every file: merged together, they would be refused
    assert set(merged) == {Key("hopper", "pos", name) for name in (
        "mujoco-state.rows.bn-mlp.cs294-ab12ab12.raw", "mujoco-state.rows.bn-mlp.cs294-ab12ab12",
        "mujoco-state.rows.bn-mlp.cs294-cd34cd34.raw", "mujoco-state.rows.bn-mlp",
        "mujoco-state.rows.bn-mlp.rough.raw")}
    raw = merged[Key("hopper", "pos", "mujoco-state.rows.bn-mlp.cs294-ab12ab12.raw")]
    assert expert_words(raw.protocol) == "cs294 (imported, SHA-256 ab12ab12…), labels raw"
    assert raw.title == ("Hopper (mujoco-state, split by rows, recipe bn-mlp, expert cs294 (imported, SHA-256 "
                         "ab12ab12…), labels raw)")
    rough = merged[Key("hopper", "pos", "mujoco-state.rows.bn-mlp.rough.raw")]
    assert rough.title.endswith("expert rough, labels raw)")
    assert "expert" not in merged[Key("hopper", "pos", "mujoco-state.rows.bn-mlp")].title   # the task's own, clipped
    # the regime's groups: imported experts first, raw before clipped, then the shipped rough one; never the SAC one
    assert [m.protocol["name"] for m in regime_groups(merged)] == [
        "mujoco-state.rows.bn-mlp.cs294-ab12ab12.raw", "mujoco-state.rows.bn-mlp.cs294-cd34cd34.raw",
        "mujoco-state.rows.bn-mlp.cs294-ab12ab12", "mujoco-state.rows.bn-mlp.rough.raw"]
    text = report.build(files).text
    heading = ("## Protocol mujoco-state, split by rows, recipe bn-mlp, expert cs294 (imported, SHA-256 ab12ab12…), "
               "labels raw\n")
    assert heading in text
    provenance = text[text.index(heading):].splitlines()[2]
    assert f"imported from a cs294-pickle file (SHA-256 `{SHA}`), from {ORIGIN}; labels raw" in provenance
    assert "| Hopper | bn-mlp, rows, expert cs294 (imported, SHA-256 ab12ab12…), labels raw | 1 |" in text   # the map


def test_the_sections_numbers_against_bc_oh_beside_table5_with_the_diagnostics(tmp_path):
    (m,) = regime_groups(merge([_load(tmp_path, regime_file("raw"), "raw.json")]))
    t = regime_table(m)
    assert [r.label for r in t.rows] == ["BC-SO", "BC-OH", "Ours (step), THR 10% W 5", "Ours (softmax), τ 0.2",
                                         "FCA (TCA), α 0.1", "FCA (TCA), α 2", "BC-full (full state: the ceiling)"]
    rows = {r.label: r for r in t.rows}
    assert [r.normalized.mean for r in t.rows] == pytest.approx([20, 30, 50, 30, 15, 35, 70])
    assert rows["BC-OH"].normalized.seeds == pytest.approx((29.5, 30.0, 30.5)) and rows["BC-OH"].versus is None
    ours, soft, fca = rows["Ours (step), THR 10% W 5"], rows["Ours (softmax), τ 0.2"], rows["FCA (TCA), α 0.1"]
    assert ours.versus.diff == pytest.approx(20) and 18.5 <= ours.versus.low < 20 < ours.versus.high <= 21.5
    assert soft.versus.diff == pytest.approx(0) and soft.versus.low < 0 < soft.versus.high
    assert fca.versus.diff == pytest.approx(-15) and fca.versus.high < 0
    assert [r.paper for r in t.rows] == [275, 293, 641, None, 1086, 1086, None] and t.paper_bcoh == 293
    assert t.share.share == pytest.approx((30 - 20) / (70 - 20))
    d = rows["BC-OH"].diagnostics
    assert (d.controlled, d.judged, d.copycats, d.read) == (2, 3, 3, 3)
    assert d.control.median == pytest.approx(0.22) and d.predictability.median == pytest.approx(0.35)
    assert rows["BC-SO"].diagnostics.controlled == 0

    built = report.build(m.sources)
    text = built.pages["index.md"].text
    section = text[text.index("## Table 5 with FCA's expert"):]
    section = section[:section.index("\n## ")]
    lines = section.splitlines()
    assert "**Hopper, expert cs294 (imported, SHA-256 ab12ab12…), labels raw**: 30,000 iterations, 3 seeds per " \
           "configuration." in lines
    assert any(line.startswith("- expert `hopper-cs294`, imported from a cs294-pickle file") and SHA in line
               and ORIGIN in line for line in lines)
    bcso = next(line for line in lines if line.startswith("| BC-SO | 3 |"))
    assert bcso.startswith("| BC-SO | 3 | 20.0 [18.8, 21.2]") and f"| 275 | {275 / 293:.2f}× | **-10.0 [" in bcso
    assert bcso.endswith("| BC-OH better |")
    step = next(line for line in lines if line.startswith("| Ours (step), THR 10% W 5 | 3 |"))
    assert "| 1,000 [975, 1,025] | 1.67× | 641 | 2.19× | **+20.0 [" in step and step.endswith("| Ours (step), "
                                                                                             "THR 10% W 5 better |")
    assert next(line for line in lines if line.startswith("| Ours (softmax), τ 0.2 | 3 |")).endswith(
        "| not significant (CI contains 0) |")
    assert "| BC-OH | 2/3 | 3/3 | 0.22 (0.2–0.4) | 0.35 (0.3–0.6) | 0.4 (0.4–0.4) |" in lines
    assert any(line.startswith("The history's share of the gap to BC-full") and ": 20% [" in line
               and "of +50.0 points" in line for line in lines)
    # the findings' block: the returns table alone
    assert "### Table 5 with FCA's expert" in built.summary and bcso in built.summary
    assert "| BC-OH | 2/3 | 3/3 |" not in built.summary


def test_the_section_is_absent_without_a_file_of_the_regime(tmp_path):
    sac = regime_file("clipped", expert=None, found={"kind": "checkpoint"})
    assert "Table 5 with FCA's expert" not in report.build([_load(tmp_path, sac, "sac.json")]).text
    ppo = regime_file("clipped", expert="ppo", found={**SHIPPED, "path": "envs/experts/hopper-ppo"})
    assert regime_groups(merge([_load(tmp_path, ppo, "ppo.json")])) == []   # a shipped variant, clipped labels


def test_a_file_without_references_is_refused_by_the_report_in_one_line(tmp_path, capsys):
    bad = _write(tmp_path, "noref.json", regime_file("raw", references=False))
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("kept\n")
    with pytest.raises(SystemExit) as e:
        report.main([str(bad), "--out", str(out)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert "noref.json: records no expert reference returns (expert.return_mean is null)" in err
    assert "random_return_mean" in err and "--set protocol.expert=NAME" in err
    assert out.read_text() == "kept\n" and not (tmp_path / "figures").exists()
    # a task judged by a rate has no expert return to need: ToyCar's files stay readable
    toycar = _results("toycar")
    toycar["expert"] = {"return_mean": None, "return_std": None, "random_return_mean": None}
    check_references(_load(tmp_path, toycar, "toycar.json"))   # no error


def test_a_file_without_references_is_refused_by_compare_in_one_line(tmp_path, capsys):
    mine = regime_file("raw", methods=METHODS[:2] + (("action-norm", {}, 700.0),), references=False)
    refs = tmp_path / "refs"
    refs.mkdir()
    _write(refs, "ref.json", regime_file("raw", methods=METHODS[:3], references=False))
    yours = _write(tmp_path, "mine.json", mine)
    with pytest.raises(SystemExit) as e:
        compare.main([str(yours), "--against", str(refs), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "mine.json: records no expert reference returns" in err
    assert not (tmp_path / "out" / "compare.md").exists()


def test_a_regime_files_bootstrap_is_seeded(tmp_path):
    (m,) = regime_groups(merge([_load(tmp_path, regime_file("raw"), "raw.json")]))
    a, b = regime_table(m), regime_table(m)
    assert a.rows == b.rows and np.isfinite([r.normalized.low for r in a.rows]).all()


def test_the_later_methods_follow_fca_in_their_order_before_bc_full(tmp_path):
    """PALR and the remedies after it (listed out of order on purpose) are rows after FCA in `LATER`'s order, BC-full
    last, each against BC-OH and with no Table 5 number."""
    later = (("priming", {"weight": 1.0}, 700.0), ("ptp", {"weight": 1.0}, 800.0),
             ("action-chunks", {"k": 100.0, "m": 0.01}, 500.0), ("palr", {"bandwidth": 1.0, "weight": 10.0}, 640.0),
             ("channel-dropout", {"rate": 0.5}, 900.0))
    (m,) = regime_groups(merge([_load(tmp_path, regime_file(methods=METHODS + later), "raw.json")]))
    t = regime_table(m)
    assert [r.method for r in t.rows][5:] == ["fca", "palr", "channel-dropout", "ptp", "action-chunks", "priming",
                                              "bc-full"]
    rows = {r.method: r for r in t.rows}
    assert [rows[k].label for k in ("channel-dropout", "ptp", "action-chunks", "priming")] == [
        "ChannelDropout", "PTP", "ActionChunks", "Priming"]
    assert rows["ptp"].versus.diff == pytest.approx(10) and rows["ptp"].versus.low > 0 and rows["ptp"].paper is None
    assert rows["channel-dropout"].normalized.mean == pytest.approx(45)
