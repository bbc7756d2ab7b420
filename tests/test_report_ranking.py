"""The later methods (RAP, PALR, MINE and the remedies after them) ranked in the report: cells by family (by setting:
where copying is expected, the default tasks), each method's best configuration per cell against BC-OH, the IQM and
probability of improvement across cells, a method missing from a cell left out of that family, and the section with
its figure.

Fixtures: `test_report_regime`'s synthetic expert-regime file (FCA's imported expert, raw labels; 3 seeds, % of
expert = return / 20, seeds at ±0.5 points) beside a file of the later methods on the same rows, as the queue's
`*-after` sweeps write them, and the same pair on a default task (the shipped expert, clipped labels)."""

import numpy as np
import pytest

from experiments import report
from experiments import stats
from experiments.report.analysis import is_copycat_cell, merge, onpolicy_check, ranking, ranking_cells
from test_report_regime import SHIPPED, _load, regime_file

# the later methods' returns: RAP 50% (two settings, the better one ranked), PALR 32%, MINE 10% (BC-OH 30%)
LATER = (("rap", {"memory_width": 150, "weight": 1.0}, 1000.0), ("rap", {"memory_width": 150, "weight": 0.0}, 500.0),
         ("palr", {"bandwidth": 1.0, "weight": 10.0}, 640.0), ("mine", {"weight": 0.1}, 200.0))
PAPER = (("bc-so", {}, 400.0), ("bc-oh", {}, 600.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 700.0))
# the remedies published after the paper, as their own sweep writes them: PTP 40%, ActionChunks 25% (BC-OH 30%)
REMEDIES = (("ptp", {"weight": 1.0}, 800.0), ("action-chunks", {"k": 100.0, "m": 0.01}, 500.0))


def _pair(tmp_path, prefix, later=LATER, **kw):
    return [_load(tmp_path, regime_file(methods=PAPER, **kw), f"{prefix}.json"),
            _load(tmp_path, regime_file(methods=later, **kw), f"{prefix}-after.json")]


def test_cells_by_setting_and_each_methods_best_configuration_against_bc_oh(tmp_path):
    files = _pair(tmp_path, "fca") + _pair(tmp_path, "sac", labels="clipped", expert=None,
                                           found={"kind": "checkpoint"})
    merged = merge(files)
    cells = ranking_cells(merged)
    assert [len(cells[k]) for k in ("copycat", "default")] == [1, 1]
    assert is_copycat_cell(cells["copycat"][0]) and not is_copycat_cell(cells["default"][0])
    copycat, default = ranking(merged, reps=200)
    assert (copycat.name, default.name) == ("copycat", "default")
    assert [r.method for r in copycat.ranked] == ["rap", "ours-step", "palr", "bc-oh", "bc-so", "mine"]
    rap = copycat.ranked[0]
    (cell,) = rap.cells
    assert cell.hparams == {"memory_width": 150, "weight": 1.0} and cell.seeds == pytest.approx((49.5, 50, 50.5))
    assert cell.versus.diff == pytest.approx(20) and cell.versus.low > 0
    assert rap.improvement.value == pytest.approx(1.0)                     # every RAP run beats every BC-OH run
    mine = copycat.ranked[-1]
    assert mine.cells[0].versus.high < 0 and mine.improvement.value == pytest.approx(0.0)
    palr = next(r for r in copycat.ranked if r.method == "palr")
    assert palr.improvement.value == pytest.approx(1.0) and palr.cells[0].versus.diff == pytest.approx(2)
    bcoh = next(r for r in copycat.ranked if r.method == "bc-oh")
    assert bcoh.improvement is None and bcoh.cells[0].versus is None
    assert bcoh.cells[0].diagnostics.controlled == 2                       # the fixture's BC-OH: 2 of 3 copycat
    assert bcoh.iqm.value == pytest.approx(stats.iqm(np.asarray([29.5, 30.0, 30.5])))
    assert bcoh.iqm.low <= bcoh.iqm.value <= bcoh.iqm.high


def test_a_cells_title_names_its_expert_and_labels_where_they_matter(tmp_path):
    """FCA's expert with raw or clipped labels: two cells, titled apart; the shipped expert's clipped labels unnamed."""
    files = (_pair(tmp_path, "raw") + _pair(tmp_path, "clipped", labels="clipped")
             + _pair(tmp_path, "sac", labels="clipped", expert=None, found={"kind": "checkpoint"}))
    copycat, default = ranking(merge(files), reps=50)
    assert set(copycat.cells) == {"Hopper (FCA's expert, raw labels)", "Hopper (FCA's expert, clipped labels)"}
    assert default.cells == ("Hopper",)


def test_a_method_missing_from_a_cell_is_left_out_of_its_family(tmp_path):
    files = _pair(tmp_path, "fca") + _pair(tmp_path, "rough", later=LATER[:2], expert="rough", found=SHIPPED)
    (copycat,) = ranking(merge(files), reps=200)
    assert len(copycat.cells) == 2
    assert {r.method for r in copycat.ranked} == {"bc-so", "bc-oh", "ours-step", "rap"}   # PALR, MINE: one cell
    assert all(len(r.cells) == 2 for r in copycat.ranked)
    fca = "Hopper (FCA's expert, raw labels)"
    assert copycat.partial == (("palr", (fca,)), ("mine", (fca,)))                    # named, not ranked
    text = report.build(files).text
    assert f"\n\nNot ranked here, as they ran in some of these cells only: PALR, in {fca}; MINE, in {fca}.\n\n" in text
    assert "## The methods that came after: RAP, ranked" in text                       # the title: ranked ones only


def test_no_later_method_no_section_and_the_section_with_its_figure(tmp_path):
    paper_only = [_load(tmp_path, regime_file(methods=PAPER), "only.json")]
    assert ranking(merge(paper_only)) == []
    assert "The methods that came after" not in report.build(paper_only).text

    built = report.build(_pair(tmp_path, "fca"), figure_dir=tmp_path / "fig")
    text, figures = built.pages["index.md"].text, built.figures
    section = text[text.index("## The methods that came after: RAP, PALR, MINE, ranked"):]
    section = section[:section.index("\n## ")]
    assert "ranking.png" in section and tmp_path / "fig" / "ranking.png" in figures
    rows = [line for line in section.splitlines() if line.startswith("| ")]
    assert rows[0].startswith("| method | IQM, % of expert [95% CI] | P(> BC-OH) [95% CI] | Hopper (")
    assert rows[0].endswith("| Hopper (FCA's expert, raw labels) |")
    assert rows[1].startswith("| RAP | 50.0 [49.") and "| 1.00 [1.00, 1.00] | **+20.0 [" in rows[1]
    assert rows[1].endswith("0/3 (first verdict 0/3) |")
    assert "reference; 2/3 (first verdict 3/3)" in next(r for r in rows if r.startswith("| BC-OH |"))
    assert "ranking.png)" in built.summary   # and in the findings' block


def test_the_remedies_are_later_methods_ranked_against_bc_oh(tmp_path):
    """A file of PTP and ActionChunks alone beside the paper's methods makes a cell; both are ranked against BC-OH,
    and the section's title names the later methods that ran, in `LATER`'s order (RAP, PALR, MINE first)."""
    files = _pair(tmp_path, "fca", later=REMEDIES)
    (copycat,) = ranking(merge(files), reps=200)
    assert [r.method for r in copycat.ranked] == ["ptp", "ours-step", "bc-oh", "action-chunks", "bc-so"]
    ptp, chunks = copycat.ranked[0], copycat.ranked[3]
    assert ptp.cells[0].versus.diff == pytest.approx(10) and ptp.cells[0].versus.low > 0
    assert ptp.improvement.value == pytest.approx(1.0) and chunks.improvement.value == pytest.approx(0.0)
    assert chunks.cells[0].hparams == {"k": 100.0, "m": 0.01} and chunks.cells[0].versus.high < 0

    text = report.build(files).text
    section = text[text.index("## The methods that came after: PTP, ActionChunks, ranked"):]
    assert "\n| PTP | 40.0 [" in section and "\n| ActionChunks | 25.0 [" in section
    both = report.build([*_pair(tmp_path, "fca"), _load(tmp_path, regime_file(methods=REMEDIES), "fca-remedies.json")])
    assert "## The methods that came after: RAP, PALR, MINE, PTP, ActionChunks, ranked" in both.text


def _at(obj, protocol=None, preset=None, iterations=None):
    """`obj` (a `regime_file`) under another protocol, or trained to another budget by its preset."""
    if protocol is not None:
        obj["protocol"] = obj["settings"]["protocol"] = {**obj["protocol"], **protocol}
    if preset is not None:
        obj["preset"] = preset
        obj["config"]["iterations"] = obj["config"]["preset_iterations"] = iterations
        obj["settings"]["budget"]["iterations"] = iterations
    return obj


def test_a_longer_run_of_a_later_method_stays_out_of_the_families(tmp_path):
    """The paper's 300k run of Table 5 with PALR in it is a group of its own; in the family it would leave out every
    method it lacks (RAP, MINE here), so the ranking reads the preset's budget only, as without it."""
    files = _pair(tmp_path, "fca")
    longer = _load(tmp_path, _at(regime_file(methods=(*PAPER, LATER[2])), preset="paper", iterations=300_000),
                   "fca-paper.json")
    assert [len(v) for v in ranking_cells(merge([*files, longer])).values()] == [1]
    (alone,), (beside,) = ranking(merge(files), reps=50), ranking(merge([*files, longer]), reps=50)
    assert beside.cells == alone.cells and [r.method for r in beside.ranked] == [r.method for r in alone.ranked]


def test_two_cells_of_one_setting_are_titled_in_full_alike_in_every_row(tmp_path):
    """Two cells that `cell_title` cannot tell apart (one setting, two protocols) take the groups' full titles, in
    the family's cells and in every method's results, so the probability of improvement pairs them."""
    sac = {"labels": "clipped", "expert": None, "found": {"kind": "checkpoint"}}
    other = {"name": "fca-train10k", "train_transitions": 10_000}
    files = _pair(tmp_path, "sac", **sac) + [
        _load(tmp_path, _at(regime_file(methods=m, **sac), protocol=other), f"sac10k-{i}.json")
        for i, m in enumerate((PAPER, LATER))]
    (default,) = ranking(merge(files), reps=50)
    assert default.name == "default"
    assert len(default.cells) == 2 and len(set(default.cells)) == 2 and "Hopper" not in default.cells
    for r in default.ranked:
        assert tuple(c.cell for c in r.cells) == default.cells
    rap = next(r for r in default.ranked if r.method == "rap")
    assert rap.improvement.value == pytest.approx(1.0)


# the on-policy check's files, as results/queue/onpolicy-check.sh writes them: DAgger and HistoryDropout alone
ONLINE_CLEARS = (("dagger", {}, 1200.0), ("history-dropout", {"p": 0.5}, 610.0))    # DAgger 60%, HD 30.5%
ONLINE_FAILS = (("dagger", {}, 560.0), ("history-dropout", {"p": 0.5}, 500.0))      # DAgger 28%, HD 25%


def test_the_on_policy_check_reads_each_copycat_cell_sound_or_not(tmp_path):
    """DAgger above BC-OH's interval: the cell is sound; DAgger within it: not; the default tasks are not checked;
    the section's table names each cell, BC-OH − BC-SO, both methods against BC-OH and the reading."""
    sac = {"labels": "clipped", "expert": None, "found": {"kind": "checkpoint"}}
    files = [*_pair(tmp_path, "raw"), _load(tmp_path, regime_file(methods=ONLINE_CLEARS), "raw-onpolicy.json"),
             *_pair(tmp_path, "clipped", labels="clipped"),
             _load(tmp_path, regime_file(methods=ONLINE_FAILS, labels="clipped"), "clipped-onpolicy.json"),
             *_pair(tmp_path, "sac", **sac), _load(tmp_path, regime_file(methods=ONLINE_CLEARS, **sac), "sac-on.json")]
    checks = {c.cell: c for c in onpolicy_check(merge(files))}
    assert set(checks) == {"Hopper (FCA's expert, raw labels)", "Hopper (FCA's expert, clipped labels)"}
    raw, clipped = checks["Hopper (FCA's expert, raw labels)"], checks["Hopper (FCA's expert, clipped labels)"]
    assert raw.sound is True and clipped.sound is False
    assert raw.history.diff == pytest.approx(10)                        # BC-OH 30% − BC-SO 20%
    assert raw.methods["dagger"].versus.diff == pytest.approx(30) and raw.methods["dagger"].versus.low > 0
    assert clipped.methods["dagger"].versus.high < 0                    # 28% against 30%, seeds at ±0.5
    assert raw.methods["history-dropout"].versus.diff == pytest.approx(0.5)

    text = report.build(files).text
    section = text[text.index("## The on-policy check where copying is expected"):]
    rows = [line for line in section[:section.index("\n## ")].splitlines() if line.startswith("| ")]
    assert rows[0] == ("| cell | BC-OH, % of expert; copycat | BC-OH − BC-SO | DAgger (online) − BC-OH; copycat | "
                       "HistoryDropout − BC-OH; copycat | reading |")
    raw_row = next(r for r in rows if r.startswith("| Hopper (FCA's expert, raw labels) | 30.0; "))
    assert "| **+30.0 [" in raw_row and raw_row.endswith("| sound: DAgger clears BC-OH, and BC-OH copies (2/3): "
                                                         "room for a remedy of copying |")
    assert any(r.endswith("something besides copying holds this cell down |") for r in rows)
    assert onpolicy_check(merge(_pair(tmp_path, "plain"))) == []        # no DAgger, no HistoryDropout: no check


def test_a_cell_without_copying_reads_so_whether_dagger_clears_bc_oh_or_not(tmp_path):
    """No BC-OH seed judged copycat by the controlled verdict and the history's interval above 0: the reading says
    there is no copying to remedy (DAgger below BC-OH), or that DAgger lifts something besides copying (above)."""
    def honest(obj):
        for run in obj["runs"]:
            if run["method"] == "bc-oh":
                run["diagnostics"] = {**run["diagnostics"], "control_ratio": 1.0, "predictability_ratio": 1.2,
                                      "controlled_verdict": "not copycat"}
        return obj

    files = [_load(tmp_path, honest(regime_file(methods=PAPER, labels="clipped")), "c.json"),
             _load(tmp_path, honest(regime_file(methods=ONLINE_FAILS, labels="clipped")), "c-onpolicy.json")]
    (check,) = onpolicy_check(merge(files))
    assert check.sound is False and check.history.low > 0 and check.bcoh.diagnostics.controlled == 0
    text = report.build(files).text
    assert ("| no copying to remedy: no BC-OH policy judged copycat and the history helps; DAgger does not clear "
            "BC-OH either |") in text
    # DAgger above BC-OH where BC-OH does not copy: what on-policy data lifts there is not copying
    files[1] = _load(tmp_path, honest(regime_file(methods=ONLINE_CLEARS, labels="clipped")), "c-onpolicy.json")
    (check,) = onpolicy_check(merge(files))
    assert check.sound is True
    assert ("| DAgger clears BC-OH, but no BC-OH policy copies and the history helps: on-policy data lifts something "
            "besides copying |") in report.build(files).text
