"""The report's full-state ceiling (`bc-full` in the state tables, the history's share of the gap) and the previous
action in view as a setting of its own in the copycat map."""

import numpy as np
import pytest

from experiments import report
from experiments.report.analysis import (CEILING_LABEL, Key, gap_share, extended_map, history_share, merge,
                                         variant_name)
from experiments.report.sections.state import ceiling_table, state_table
from test_report import _fca, _loaded, _results, _schema2

BASE = (("bc-so", {}, 400.0), ("bc-oh", {}, 1000.0), ("ours-step", {"thr": 0.1, "w": 5.0}, 1100.0))


def test_the_share_is_the_ratio_of_the_differences_of_means_with_an_interval_around_it():
    a, b, c = [9.0, 11.0, 10.0], [0.0, 1.0, -1.0], [20.0, 19.0, 21.0]
    s = gap_share(a, b, c)
    assert s.share == pytest.approx(0.5) and s.low < 0.5 < s.high and (s.n_a, s.n_b, s.n_c) == (3, 3, 3)
    assert s.high - s.low < 0.2
    assert gap_share(a, b, b) is None                       # no gap to share
    assert gap_share(a, b, c) == gap_share(a, b, c)   # seeded


def test_bc_full_joins_the_state_table_as_the_ceiling_and_the_report_states_the_historys_share(tmp_path):
    with_full = _schema2(_results("hopper", BASE + (("bc-full", {}, 1600.0),)))
    without = _schema2(_results("walker2d", BASE))
    merged = merge([_loaded(tmp_path, with_full, "h.json"), _loaded(tmp_path, without, "w.json")])
    table = state_table(merged, "pos", "brax")
    assert f"| {CEILING_LABEL} | 1,600 ± 14 (80%) | — |" in table   # ± the sample sd over 2 seeds, ∓ 10
    assert table.index("| BC-OH |") < table.index(CEILING_LABEL) < table.index("| expert (ours) |")
    # (1,000 − 400) / (1,600 − 400) = 50%; Walker2d has no BC-full: no share
    share = history_share(merged[Key("hopper", "pos", "brax")])
    assert share.share == pytest.approx(0.5) and share.low <= 0.5 <= share.high
    assert history_share(merged[Key("walker2d", "pos", "brax")]) is None
    lines = ceiling_table(merged, "pos", "brax").splitlines()
    assert lines[2].startswith("| (BC-OH − BC-SO) / (BC-full − BC-SO) | 50% [") and lines[2].endswith("| — |")
    assert "of +1,200" in lines[2]
    text = report.report([_loaded(tmp_path, with_full, "h.json")])
    assert CEILING_LABEL in text and "The history's share of the gap to BC-full" in text


def test_files_without_bc_full_lack_the_row_and_the_share(tmp_path):
    merged = merge([_loaded(tmp_path, _schema2(_results("hopper", BASE)))])
    assert CEILING_LABEL not in state_table(merged, "pos", "brax")
    assert ceiling_table(merged, "pos", "brax") == ""


def test_the_previous_action_in_view_is_a_setting_of_its_own_in_the_copycat_map(tmp_path):
    def fca_file(prev: bool, bcoh: float):
        obj = _schema2(_results("hopper", (("bc-so", {}, 600.0), ("bc-oh", {}, bcoh),
                                           ("ours-step", {"thr": 0.1, "w": 5.0}, 900.0))),
                       protocol={**_fca(1), "split": "rows", **({"prev_action": True} if prev else {})})
        return obj

    plain, prev = (_loaded(tmp_path, fca_file(p, b), f"{p}.json") for p, b in ((False, 1000.0), (True, 300.0)))
    assert variant_name(prev, prev.protocol) == "mujoco-state.rows.mlp.prev"
    assert variant_name(plain, plain.protocol) == "mujoco-state.rows.mlp"
    merged = merge([plain, prev])
    assert set(k.protocol for k in merged) == {"mujoco-state.rows.mlp", "mujoco-state.rows.mlp.prev"}
    points = extended_map(merged)
    assert [q.prev_action for q in points] == [False, True]
    assert points[1].setting.endswith(", previous action in view") and "previous" not in points[0].setting
    assert np.isclose(points[1].cells[1].mean, 15.0)     # BC-OH's 300 of the expert's 2,000
    text = report.report([plain, prev])
    assert "| Hopper | mlp, rows, previous action in view | 1 |" in text


def test_the_extended_map_shows_bc_full_and_the_historys_share_where_it_ran(tmp_path):
    def fca_file(methods, prev=False):
        return _schema2(_results("hopper", methods), protocol={**_fca(1), "split": "rows",
                                                               **({"prev_action": True} if prev else {})})

    files = [_loaded(tmp_path, fca_file(BASE + (("bc-full", {}, 1600.0),)), "full.json"),
             _loaded(tmp_path, fca_file(BASE, prev=True), "prev.json")]
    points = extended_map(merge(files))
    with_full, without = points
    assert np.isclose(with_full.ceiling.mean, 80.0) and with_full.share.share == pytest.approx(0.5)
    assert without.ceiling is None and without.share is None
    text = report.report(files)
    assert "Where BC-full (the full state) ran" in text
    assert "| Hopper | mlp, rows | 1 | 20,000 | 30k | 30k | 80.0 ± 0.7 | 50% [" in text
