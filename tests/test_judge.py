"""The controlled copycat verdict of a results file (`ape_jax.pipeline.judge`) and `experiments.evaluate --rejudge`.

The fixtures are committed results files with chosen `prev_from_embedding` and `predictability_ratio` values: the
verdict is arithmetic on the recorded diagnostics, so no policy is needed.
"""

import json
import pathlib
import shutil

import pytest

from ape_jax import diagnostics as dg
from ape_jax.pipeline import judge
from ape_jax.pipeline import results
from experiments import evaluate

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
FCA_BC = RESULTS / "hopper-pos-fca-rows-default-fca-bc.json"    # BC-SO, BC-OH, Ours (10% × 5), 5 seeds, 30k
FCA_FCA = RESULTS / "hopper-pos-fca-rows-default-fca-fca.json"  # FCA only: the same data, protocol, recipe, budget
MLP_BC = RESULTS / "hopper-pos-fca-rows-default-mlp-bc.json"    # another recipe


def _set(run: dict, prev: float, pred: float) -> None:
    run["diagnostics"].update(prev_from_embedding=prev, predictability_ratio=pred)


def _fixture() -> dict:
    """FCA_BC with BC-SO's errors 0.001, 0.02, 0.03, 0.04, 0.05 (median 0.03) and BC-OH's 0.006 (seed 0) or 0.009,
    every predictability 0.1; not yet judged (the committed file is: its controlled verdict taken off)."""
    obj = json.loads(FCA_BC.read_text())
    obj["config"]["diagnostics"].pop("control", None)
    obj["config"]["diagnostics"]["thresholds"].pop("control_ratio", None)
    for run in obj["runs"]:
        for k in judge.CONTROL_FIELDS:
            run["diagnostics"].pop(k, None)
        if run["method"] == "bc-so":
            _set(run, [0.001, 0.02, 0.03, 0.04, 0.05][run["seed"]], 0.1)
        elif run["method"] == "bc-oh":
            _set(run, 0.006 if run["seed"] == 0 else 0.009, 0.1)
    return obj


def _runs(res: results.Results, method: str) -> list[dict]:
    return sorted((r for r in res.runs if r["method"] == method), key=lambda r: r["seed"])


def test_a_file_is_judged_against_the_median_of_its_own_bc_so_and_keeps_its_first_verdict():
    res = results.Results.from_json(_fixture())
    judged = judge.judge(res)
    bc_oh, bc_so = _runs(judged, "bc-oh"), _runs(judged, "bc-so")
    assert bc_oh[0]["diagnostics"]["control_ratio"] == pytest.approx(0.2)      # 0.006 / 0.03
    assert bc_oh[1]["diagnostics"]["control_ratio"] == pytest.approx(0.3)      # 0.009 / 0.03: above 0.25
    assert [r["diagnostics"]["controlled_verdict"] for r in bc_oh] == ["copycat"] + ["not copycat"] * 4
    # BC-SO's seed 0 holds a_{t−1} 30× better than its median and is smooth, but it has no past: never a copycat
    assert bc_so[0]["diagnostics"]["control_ratio"] == pytest.approx(1 / 30)
    assert all(r["diagnostics"]["controlled_verdict"] == "not copycat" for r in bc_so)
    # the first verdict and every recorded number as they were; only the two fields added
    for old, new in zip(res.runs, judged.runs):
        assert {k: v for k, v in new["diagnostics"].items() if k not in judge.CONTROL_FIELDS} == old["diagnostics"]
    control = judged.config["diagnostics"]["control"]
    assert control["file"] is None and control["method"] == "bc-so"
    assert control["at"] == [{"iteration": 30_000, "seeds": 5, "prev_from_embedding": pytest.approx(0.03)}]
    assert judged.config["diagnostics"]["thresholds"] == {"embedding_ratio": 0.5, "predictability_ratio": 0.5,
                                                          "control_ratio": 0.25}
    assert "control" not in res.config["diagnostics"] and "control_ratio" not in res.runs[0]["diagnostics"]  # pure
    again = judge.judge(judged)
    assert again.to_json() == judged.to_json()                                  # idempotent
    results.Results.from_json(judged.to_json())                                 # and a valid file


def test_snapshots_are_judged_against_the_control_at_the_same_iteration():
    obj = _fixture()
    for run in obj["runs"]:
        if run["method"] in ("bc-so", "bc-oh"):
            snap = {**run["diagnostics"], "prev_from_embedding": 0.1 if run["method"] == "bc-so" else 0.02}
            run["at"] = [{"iteration": 10_000, "eval": run["eval"], "diagnostics": snap}]
        if run["method"] == "ours-step":   # an iteration the control was not evaluated at
            run["at"] = [{"iteration": 20_000, "eval": run["eval"], "diagnostics": dict(run["diagnostics"])}]
    judged = judge.judge(results.Results.from_json(obj))
    at = [r["at"][0]["diagnostics"] for r in _runs(judged, "bc-oh")]
    assert [d["control_ratio"] for d in at] == [pytest.approx(0.2)] * 5            # 0.02 / 0.1, not / 0.03
    assert all(d["controlled_verdict"] == "copycat" for d in at)
    assert all(judge.CONTROL_FIELDS[0] not in r["at"][0]["diagnostics"] for r in _runs(judged, "ours-step"))
    assert [a["iteration"] for a in judged.config["diagnostics"]["control"]["at"]] == [10_000, 30_000]


def test_who_sees_a_past_and_who_can_be_the_control():
    res = results.Results.from_json(_fixture())
    assert not judge.sees_past(res, "bc-so") and judge.sees_past(res, "bc-oh") and judge.sees_past(res, "plugin-x")
    obj = _fixture()
    obj["settings"]["protocol"]["prev_action"] = True      # the previous action in the observation
    poa = results.Results.from_json(obj)
    assert judge.sees_past(poa, "bc-so") and judge.control_errors(poa) == {}
    with pytest.raises(judge.JudgeError, match="see the previous action"):
        judge.judge(poa)
    # its control comes from the sibling without the previous action in view
    judged = judge.judge(poa, judge.find_control(poa, [("plain.json", res)]))
    assert judged.config["diagnostics"]["control"]["file"] == "plain.json"
    # BC-SO with the previous action in view, holding a_{t−1} 30× better than the control and smooth: judged
    seed0 = _runs(judged, "bc-so")[0]["diagnostics"]
    assert seed0["control_ratio"] == pytest.approx(1 / 30) and seed0["controlled_verdict"] == "copycat"


def test_a_sibling_controls_only_with_the_same_demonstrations_protocol_recipe_budget_and_probe():
    fca = results.load(FCA_FCA)
    assert not judge.control_errors(fca)
    with pytest.raises(judge.JudgeError, match="no bc-so policy"):
        judge.judge(fca)
    bc, mlp = results.load(FCA_BC), results.load(MLP_BC)
    assert judge.find_control(fca, [("mlp.json", mlp), ("bc.json", bc)])[0] == "bc.json"
    assert judge.find_control(fca, [("mlp.json", mlp)]) is None                 # another recipe
    for change in ({"iterations": 100_000}, {"diagnostics": {**bc.config["diagnostics"], "probe_steps": 500}},
                   {"data": {**bc.config["data"], "train_transitions": 5_000}}):
        other = results.Results.from_json({**bc.to_json(), "config": {**bc.config, **change}})
        assert judge.find_control(fca, [("other.json", other)]) is None, change
    sha = {**bc.config, "data": {**bc.config["data"], "sha256": "0" * 64}}
    mine = results.Results.from_json({**fca.to_json(), "config": {**fca.config, "data": {**fca.config["data"],
                                                                                          "sha256": "1" * 64}}})
    assert judge.find_control(mine, [("bc.json", results.Results.from_json({**bc.to_json(), "config": sha}))]) is None
    with pytest.raises(judge.JudgeError, match="does not share"):
        judge.judge(fca, ("mlp.json", mlp))
    judged = judge.judge(fca, ("bc.json", bc))
    median = sorted(r["diagnostics"]["prev_from_embedding"] for r in _runs(bc, "bc-so"))[2]
    for run in judged.runs:
        assert run["diagnostics"]["control_ratio"] == pytest.approx(run["diagnostics"]["prev_from_embedding"] / median)


# -- the command line ------------------------------------------------------------------------------------------------

def test_rejudge_writes_each_file_with_both_verdicts_finds_the_sibling_and_is_idempotent(tmp_path, capsys):
    for path in (FCA_BC, FCA_FCA, MLP_BC):
        shutil.copy(path, tmp_path / path.name)
    files = [tmp_path / FCA_BC.name, tmp_path / FCA_FCA.name]
    assert evaluate.main(["--rejudge", *map(str, files)]) == 0
    out = capsys.readouterr().out
    assert f"rejudged {files[1]}: control bc-so from {FCA_BC.name}; copycat: first verdict 0/20" in out
    first = [f.read_text() for f in files]
    for path in files:
        res = results.load(path)
        assert all(judge.readable(r)["controlled_verdict"] in ("copycat", "not copycat") for r in res.runs)
        old = json.loads((RESULTS / path.name).read_text())
        assert [r["diagnostics"]["verdict"] for r in res.runs] == [r["diagnostics"]["verdict"] for r in old["runs"]]
    assert evaluate.main(["--rejudge", *map(str, files)]) == 0
    assert [f.read_text() for f in files] == first                             # idempotent, byte for byte


def test_rejudge_refuses_a_file_without_a_control_and_writes_nothing(tmp_path, capsys):
    lone, other = tmp_path / "lone" / FCA_FCA.name, tmp_path / FCA_BC.name
    lone.parent.mkdir()
    shutil.copy(FCA_FCA, lone), shutil.copy(FCA_BC, other)
    before = [lone.read_text(), other.read_text()]
    with pytest.raises(SystemExit) as e:
        evaluate.main(["--rejudge", str(other), str(lone)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "no bc-so control" in err and str(lone) in err
    assert [lone.read_text(), other.read_text()] == before                    # the first file was not written either
    with pytest.raises(SystemExit) as e:
        evaluate.main(["--rejudge", str(lone), "--control", str(tmp_path / "missing.json")])
    assert e.value.code == 2
    assert evaluate.main(["--rejudge", str(lone), "--control", str(other)]) == 0   # named: the sibling elsewhere
    assert results.load(lone).config["diagnostics"]["control"]["file"] == FCA_BC.name
    with pytest.raises(SystemExit) as e:
        evaluate.main([str(tmp_path), "--rejudge", str(lone)])
    assert e.value.code == 2


def test_a_control_on_resampled_demonstrations_is_taken_only_when_asked_and_recorded(tmp_path, capsys):
    """One expert's demonstrations collected on another CPU differ in their bytes (float rounding diverges long
    rollouts): such a control is refused by default, taken with `--resampled`, and the file records both hashes."""
    lone, other = tmp_path / "lone" / FCA_FCA.name, tmp_path / FCA_BC.name
    lone.parent.mkdir()
    for source, path, sha in ((FCA_FCA, lone, "0" * 64), (FCA_BC, other, "1" * 64)):
        obj = json.loads(source.read_text())
        obj["config"]["data"]["sha256"] = sha
        path.write_text(json.dumps(obj))
    before = lone.read_text()
    with pytest.raises(SystemExit) as e:
        evaluate.main(["--rejudge", str(lone), "--control", str(other)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--resampled" in err and lone.read_text() == before
    with pytest.raises(SystemExit) as e:
        evaluate.main(["--rejudge", str(lone), "--resampled"])
    assert e.value.code == 2 and "--resampled goes with --control" in capsys.readouterr().err
    assert evaluate.main(["--rejudge", str(lone), "--control", str(other), "--resampled"]) == 0
    control = results.load(lone).config["diagnostics"]["control"]
    assert control["file"] == FCA_BC.name and control["demonstrations"]["file"] == "0" * 64
    assert control["demonstrations"]["control"] == "1" * 64
    assert all(judge.readable(r)["controlled_verdict"] in ("copycat", "not copycat") for r in results.load(lone).runs)


def test_rejudge_skips_a_file_without_diagnostics(tmp_path, capsys):
    obj = json.loads(FCA_BC.read_text())
    for run in obj["runs"]:
        run.pop("diagnostics")
    obj["config"].pop("diagnostics")
    path = tmp_path / "plain.json"
    path.write_text(json.dumps(obj))
    before = path.read_text()
    assert evaluate.main(["--rejudge", str(path)]) == 0
    assert f"skipped {path}: no copycat diagnostics" in capsys.readouterr().out and path.read_text() == before


def test_the_committed_verdicts_are_the_judge_s():
    """Every committed results file with diagnostics carries the controlled verdict its control gives (re-judging
    it changes nothing; BC-OH and ours at 100k under the first recipe take theirs from the BC-SO trained for it,
    `hopper-pos-fca-default-long-bcso.json`)."""
    unjudged = []
    for path in sorted(RESULTS.glob("*.json")):
        res = results.load(path)
        if not any(judge.readable(r) for r in res.runs):
            continue
        control = res.config.get("diagnostics", {}).get("control")
        if control is None:
            unjudged.append(path.name)
            continue
        source = None if control["file"] is None else (control["file"], results.load(RESULTS / control["file"]))
        resampled = "demonstrations" in control   # judged with `--resampled`: the same settings, other bytes
        assert judge.judge(res, source, resampled=resampled).to_json() == res.to_json(), path.name
    assert unjudged == []
    assert dg.THRESHOLDS.control_ratio == 0.25
