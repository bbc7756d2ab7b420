"""The shipped reference printed under a short sweep's table (`experiments._reference`): the committed rows of the
same setting at longer budgets, this run's beside them, and a reading that says when the order disagrees."""

import json
import pathlib

from ape_jax.pipeline import results
from experiments._reference import comparable, reference_lines

ROOT = pathlib.Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "results"
THIRTY_K = SHIPPED / "hopper-pos-fca-rows-default-fca-bc.json"   # BC-SO, BC-OH, ours-step at 30k, 5 seeds


def _short_run(tmp_path, so: float, oh: float, iterations=3_000, **changes) -> pathlib.Path:
    """A 1-seed file of the 30k file's setting at `iterations`, BC-SO and BC-OH at `so` and `oh` % of expert."""
    obj = json.loads(THIRTY_K.read_text())
    obj["settings"]["budget"].update(iterations=iterations, seeds=1)
    obj["config"].update(iterations=iterations, seeds=1)
    for section, values in changes.items():
        obj["settings"][section].update(values)
    runs = [r for r in obj["runs"] if r["seed"] == 0]
    for r in runs:
        r["eval"]["normalized"] = {"bc-so": so, "bc-oh": oh}.get(r["method"], 10.0)
    obj["runs"], obj["summary"] = runs, results.summarize(runs)
    path = tmp_path / "results.json"
    path.write_text(json.dumps(obj))
    return path


def test_a_short_run_is_shown_under_the_shipped_rows_of_its_setting_and_its_reversed_order_is_named(tmp_path):
    lines = reference_lines(_short_run(tmp_path, so=23.5, oh=4.7))
    text = "\n".join(lines)
    assert lines[0].startswith("shipped reference: hopper (pos), protocol mujoco-state, recipe bn-mlp")
    budgets = [line.split()[0] for line in lines[2:-1]]
    assert budgets == ["30,000", "300,000", "3,000"]            # the shipped budgets in order, then this run
    assert "51.9 [37.2, 66.6]" in lines[2] and "80.4 [64.4, 96.3]" in lines[2]   # the 30k file's own numbers
    assert "91.3 [85.6, 97.0]" in lines[3]                      # the 300k file's BC-OH, found by its setting
    assert "23.5 (1 seed)" in lines[4] and lines[4].endswith("<- this run")
    assert "3,000 of the 300,000 iterations the answer is read at, one seed: it checks" in text
    assert "here BC-OH is below BC-SO, at 300,000 iterations it is above" in text
    assert "results/hopper-pos-fca-rows-paper-fca-bc.json" in lines[-1]


def test_a_short_run_in_the_published_order_is_not_called_reversed(tmp_path):
    text = "\n".join(reference_lines(_short_run(tmp_path, so=20.0, oh=60.0)))
    assert "goes the same way as at 300,000 iterations" in text and "is below" not in text


def test_no_reference_is_printed_for_a_setting_nothing_shipped_shares(tmp_path):
    assert reference_lines(_short_run(tmp_path, 20.0, 60.0, recipe={"batch_size": 32})) == []
    assert reference_lines(_short_run(tmp_path, 20.0, 60.0), shipped=tmp_path / "none") == []


def test_a_smoke_run_gets_no_reference_and_nothing_to_compare(tmp_path):
    path = _short_run(tmp_path, 20.0, 60.0, iterations=4)
    obj = json.loads(path.read_text())
    obj["config"]["smoke"] = True
    path.write_text(json.dumps(obj))
    assert reference_lines(path) == [] and not comparable(path)


def test_only_a_run_a_shipped_file_matches_is_called_comparable(tmp_path):
    assert comparable(SHIPPED / "hopper-pos-fca-rows-default-fca-after.json")   # RAP, PALR, MINE: not references
    assert not comparable(THIRTY_K)                        # references only: nothing of its own to rank
    assert not comparable(_short_run(tmp_path, 20.0, 60.0))   # neither: references only, and at 3,000 iterations


def test_a_run_gets_the_shipped_rows_of_its_own_budget_and_the_longer_ones(tmp_path):
    lines = reference_lines(_short_run(tmp_path, 20.0, 60.0, iterations=300_000))
    assert [line.split()[0] for line in lines[2:-1]] == ["300,000", "300,000"]   # the shipped row, then this run
    assert "the budget the shipped answer is read at (300,000 iterations)" in lines[-1]
    lines = reference_lines(_short_run(tmp_path, 20.0, 60.0, iterations=30_000))
    assert [line.split()[0] for line in lines[2:-1]] == ["30,000", "300,000", "30,000"]
    assert "30,000 of the 300,000 iterations the answer is read at" in lines[-1]


def test_a_run_of_none_of_the_references_gets_the_shipped_rows_and_a_line_naming_its_methods(tmp_path):
    """The `default` sweep of methods of its own (`--methods rap,palr`): the shipped 30k row of its budget, no row of
    dashes for this run."""
    obj = json.loads(THIRTY_K.read_text())
    runs = [dict(r, method="rap" if r["method"] == "bc-so" else "palr") for r in obj["runs"]
            if r["method"] in ("bc-so", "bc-oh")]
    obj["runs"], obj["summary"] = runs, results.summarize(runs)
    path = tmp_path / "results.json"
    path.write_text(json.dumps(obj))
    lines = reference_lines(path)
    assert lines[2].split()[0] == "30,000" and "51.9 [37.2, 66.6]" in lines[2]
    assert any("this run trained none of these (rap, palr)" in line for line in lines)
    assert not any(line.rstrip().endswith("<- this run") for line in lines)


def test_a_driving_run_reads_against_the_shipped_camera_and_state_tables_and_is_told_where_they_crash():
    """A task judged by a rate (ToyTown's success): what success is, the shipped tables of its protocol per observation
    mode and task version (the camera's, version 1; the one-frame state's, version 2) with BC-full, this run beside
    them, and a reading that says plainly that the shipped camera policies crash."""
    run = SHIPPED / "toytown-image-nocrash-default-seeds0.json"   # as if a fresh run of one seed
    lines = reference_lines(run)
    assert lines[0].startswith("shipped reference: toytown, protocol nocrash, in results/ (success: the route "
                               "completed in time without a collision")
    assert "BC-full" in lines[1]
    rows = {tuple(line.split()[:3]): line for line in lines[2:-1]}
    assert ("image", "1", "10,000") in rows and ("pos", "2", "10,000") in rows
    pos = rows[("pos", "2", "10,000")]
    assert "87.4 [78.0, 96.8]" in pos and "95.4 [92.0, 98.8]" in pos and "98.6 [97.5, 99.7]" in pos
    assert lines[-2].endswith("<- this run") and "(1 seed)" in lines[-2]
    assert "the shipped image policies (version 1) crash in" in lines[-1] and "one seed" in lines[-1]
    assert "shipped pos policies" not in lines[-1]   # the state row drives
