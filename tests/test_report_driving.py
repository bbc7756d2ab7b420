"""ToyTown's driving tables in the report: a group under `nocrash` reads as the supplement's Table 1 and one under
`nocrash-nospeed` as its Table 2, each with every method that ran (in a fixed order, BC-full last), its copycat
verdicts, the paper's comparisons in numbers and a figure of success and stuck; Table 3 lists every method.

The fixtures are synthetic results files of the ToyTown sweeps' shape (schema 3, image observations, 5 seeds, the
methods of the sweeps with the hparams their grids record), built on `test_report._results`; no policy is trained.
"""

import pathlib

import numpy as np
import pytest
from PIL import Image

from ape_jax import tasks
from ape_jax.pipeline.presets import resolve
from ape_jax.pipeline.setup import protocol_setup
from experiments import report, stats
from experiments.report.analysis import (DRIVING_ORDER, Key, driving_comparisons, driving_rows, driving_table,
                                         driving_verdicts, loss_rows, merge)
from experiments.report.figures import MAX_HEIGHT, driving_figure, save_png
from test_report import _results, _schema2, _write

SEEDS = 5
# The sweeps' methods and the hparams their grids record, listed out of the table's order on purpose.
METHODS = (("mine", {"weight": 1.0}), ("bc-full", {}), ("dagger", {"rounds": 5.0, "budget": 35000.0}),
           ("bc-oh", {}), ("rap", {"weight": 1.0, "memory_width": 150.0}), ("ours-step", {"thr": 0.1, "w": 5.0}),
           ("fca", {"alpha": 0.2, "adversary_lr": 2e-4}), ("bc-so", {}), ("palr", {"weight": 1.0, "bandwidth": 1.0}),
           ("history-dropout", {"p": 0.5}), ("boosting", {"rounds": 5.0}))
# The table's order: BC-SO, BC-OH, Ours, the baselines, BC-full last.
ORDER = ("bc-so", "bc-oh", "ours-step", "fca", "history-dropout", "dagger", "boosting", "rap", "palr", "mine",
         "bc-full")
# Per method, each seed's success rate (of 40 episodes: multiples of 0.025), stuck rate and collisions per episode.
SUCCESS = {"bc-so": (0.300, 0.350, 0.400, 0.325, 0.375), "bc-oh": (0.400, 0.500, 0.450, 0.550, 0.425),
           "ours-step": (0.450, 0.500, 0.550, 0.475, 0.525), "fca": (0.350, 0.400, 0.375, 0.425, 0.450),
           "history-dropout": (0.300, 0.325, 0.350, 0.375, 0.400), "dagger": (0.600, 0.650, 0.625, 0.575, 0.700),
           "boosting": (0.250, 0.300, 0.275, 0.325, 0.350), "rap": (0.400, 0.425, 0.450, 0.475, 0.500),
           "palr": (0.375, 0.400, 0.425, 0.450, 0.475), "mine": (0.325, 0.350, 0.375, 0.400, 0.425),
           "bc-full": (0.850, 0.875, 0.900, 0.925, 0.900),
           **{k: (0.350, 0.375, 0.400, 0.425, 0.450) for k in ("channel-dropout", "ptp", "action-chunks", "priming")}}
STUCK = {**{k: (0.1, 0.15, 0.05, 0.1, 0.1) for k in SUCCESS}, "bc-oh": (0.3, 0.25, 0.35, 0.2, 0.3),
         "bc-full": (0.0,) * SEEDS}
COLLISIONS = {**{k: (0.5, 0.45, 0.4, 0.5, 0.45) for k in SUCCESS}, "bc-oh": (0.3, 0.25, 0.35, 0.2, 0.3),
              "ours-step": (0.35, 0.3, 0.3, 0.25, 0.35)}
EPISODES = 40
THRESHOLDS = {"embedding_ratio": 0.5, "predictability_ratio": 0.5, "control_ratio": 0.25}
NO_EMBEDDING = "the policy network has no embedding"


def _diagnostics(method: str, seed: int) -> dict:
    """A diagnostics block: BC-OH copycat by the first verdict in seeds 0-2 and by the controlled one in seeds 0-1,
    Ours by the first verdict in seed 0 only, MINE's seed 0 unreadable (`absent`), every other policy honest."""
    if method == "mine" and seed == 0:
        return {"absent": NO_EMBEDDING}
    first = (method == "bc-oh" and seed < 3) or (method == "ours-step" and seed == 0)
    controlled = method == "bc-oh" and seed < 2
    return {"embedding_ratio": 0.3 if first else 1.2, "prev_from_embedding": 0.003, "prev_from_action": 0.01,
            "velocity_ratio": None, "predictability_ratio": 0.4 if first else 0.9, "policy_mse": 0.001,
            "expert_mse": 0.002, "predictability_steps": 4000, "control_ratio": 0.2 if controlled else 0.8,
            "verdict": "copycat" if first else "not copycat",
            "controlled_verdict": "copycat" if controlled else "not copycat"}


def toytown_file(protocol: str = "nocrash", methods=METHODS, seeds: int = SEEDS, obs: str = "image") -> dict:
    """A schema-3 ToyTown results file as a sweep under `protocol` writes it: `obs` observations, `seeds` seeds of
    `methods`, per seed the success, stuck and collision rates of `SUCCESS`, `STUCK`, `COLLISIONS` (the other
    metrics plausible), copycat diagnostics (`_diagnostics`) and losses that differ per method."""
    settings = resolve("toytown", obs, protocol=protocol, preset="default").to_json()
    obj = _schema2(_results("toytown", tuple((m, hp, 0.0) for m, hp in methods), deltas=(0.0,) * seeds),
                   protocol=protocol_setup("toytown", obs, protocol).settings,  # the task version recorded
                   command=["python", "-m", "experiments.sweep", "--env", "toytown", "--protocol", protocol,
                            "--methods", ",".join(m for m, _ in methods)])
    iterations = settings["budget"]["iterations"]
    obj.update(schema=3, obs=obs, settings=settings, expert={"return_mean": None, "return_std": None,
                                                             "random_return_mean": None})
    obj["config"].update(iterations=iterations, preset_iterations=iterations, seeds=seeds, eval_episodes=EPISODES,
                         methods=[m for m, _ in methods], metric="success",
                         task_metrics=list(tasks.get("toytown").metrics),
                         diagnostics={"thresholds": THRESHOLDS})
    order = [m for m, _ in methods]
    for run in obj["runs"]:
        method, seed = run["method"], run["seed"]
        success, crash = SUCCESS[method][seed], COLLISIONS[method][seed]
        run["eval"].update(episodes=EPISODES, return_mean=0.8, success=success, route_completion=0.8,
                           collisions=crash, collisions_vehicle=crash / 2, collisions_pedestrian=crash / 4,
                           collisions_offroad=crash / 4, red_light_violations=0.1, timeout=1 - success - crash
                           if success + crash < 1 else 0.0, stuck=STUCK[method][seed], avg_speed=5.0,
                           normalized=100 * success)
        i = order.index(method)
        run["losses"] = {s: {"unweighted": 0.05 + 0.01 * i, "changepoint": 0.3 + 0.01 * i, "copycat": 0.02 + 0.001 * i}
                         for s in ("train", "val")}
        run["diagnostics"] = _diagnostics(method, seed)
    return obj


def _load(tmp_path, obj, name):
    return report.load(_write(tmp_path, name, obj))


def _group(tmp_path, protocol="nocrash", **kw):
    (m,) = merge([_load(tmp_path, toytown_file(protocol, **kw), f"toytown-{protocol}.json")]).values()
    return m


def _section(text: str, title: str) -> str:
    """The markdown from heading `title` to the next heading of its level."""
    part = text[text.index(title):]
    return part[:part.index("\n## ", 1)] if "\n## " in part[1:] else part


def _row(text: str, label: str) -> list[str]:
    """The cells of the table row that starts with `label`."""
    line = next(x for x in text.splitlines() if x.startswith(f"| {label} |"))
    return [c.strip() for c in line.strip("|").split("|")]


def _cells(text: str, label: str) -> dict[str, str]:
    """The cells of the row that starts with `label` in the first table of `text`, by the table's headings."""
    return dict(zip(_row(text, "method"), _row(text, label)))


def test_a_nocrash_group_reads_as_table_1_and_nocrash_nospeed_as_table_2(tmp_path):
    assert driving_table(_group(tmp_path)) == (1, "NoCrash-Dense, speed in view")
    assert driving_table(_group(tmp_path, "nocrash-nospeed")) == (2, "NoCrash-Dense without the speed")
    text = report.build([_load(tmp_path, toytown_file(p), f"{p}.json") for p in ("nocrash", "nocrash-nospeed")]).text
    assert ("## ToyTown (nocrash): the supplement's Table 1 (NoCrash-Dense, speed in view)\n" in text
            and "## ToyTown (nocrash-nospeed): the supplement's Table 2 (NoCrash-Dense without the speed)\n" in text)
    assert "Table 4 protocol" not in text


def test_every_method_is_a_row_in_the_fixed_order_with_bc_full_last_as_the_ceiling(tmp_path):
    m = _group(tmp_path)
    rows = driving_rows(m)
    assert [r.method for r in rows] == list(ORDER)
    assert [r.method for r in rows[:-1]] == [x for x in DRIVING_ORDER if x in ORDER]
    assert [r.ceiling for r in rows] == [False] * (len(ORDER) - 1) + [True]
    assert [len(r.runs) for r in rows] == [SEEDS] * len(ORDER)
    labels = [r.label for r in rows]
    assert labels[:3] == ["BC-SO", "BC-OH", "Ours, step THR 10% W 5"]
    assert labels[-1] == "BC-full (full state: the ceiling)" and "DAgger (online)" in labels
    table = _section(report.build([_load(tmp_path, toytown_file(), "t.json")]).text, "## ToyTown (nocrash)")
    lines = [x for x in table.splitlines() if x.startswith("| ") and not x.startswith("| method")]
    assert [x.split(" | ")[0][2:] for x in lines[:len(ORDER)]] == labels
    # the key columns first, so that they stay in view on a page narrower than the table
    assert ("| method | success % | collisions | stuck % | copycat: first verdict | copycat: controlled verdict | "
            "hparams | seeds | route completion | collisions vehicle | collisions pedestrian | collisions offroad | "
            "red-light violations | timeout | average speed | success % of all episodes [Wilson 95%] |") in table
    assert _cells(table, "FCA (TCA)")["hparams"] == "alpha 0.2, adversary_lr 0.0002"


def test_the_remedies_after_the_paper_follow_mine_in_their_order(tmp_path):
    """ChannelDropout, PTP, ActionChunks and Priming (listed out of order on purpose) are rows after MINE in
    `LATER`'s order, BC-full still last, in the table as in `driving_rows`."""
    remedies = (("priming", {"weight": 1.0}), ("action-chunks", {"k": 100.0, "m": 0.01}), ("ptp", {"weight": 1.0}),
                ("channel-dropout", {"rate": 0.5}))
    obj = toytown_file(methods=METHODS + remedies)
    rows = driving_rows(merge([_load(tmp_path, obj, "remedies.json")])[Key("toytown", "image", "nocrash", version=2)])
    assert [r.method for r in rows][-6:] == ["mine", "channel-dropout", "ptp", "action-chunks", "priming", "bc-full"]
    table = _section(report.build([_load(tmp_path, obj, "remedies.json")]).text, "## ToyTown (nocrash)")
    lines = [x.split(" | ")[0][2:] for x in table.splitlines() if x.startswith("| ") and not x.startswith("| method")]
    assert lines[len(ORDER) - 2:len(ORDER) + 4] == ["MINE", "ChannelDropout", "PTP", "ActionChunks", "Priming",
                                                     "BC-full (full state: the ceiling)"]


def test_ours_is_shown_at_the_papers_setting_and_a_baselines_settings_each_get_a_row(tmp_path):
    """Other step settings stay in the grid table below; FCA at two α is two rows, each named by its setting."""
    extra = (("ours-step", {"thr": 0.2, "w": 3.0}), ("fca", {"alpha": 0.5, "adversary_lr": 2e-4}))
    obj = toytown_file(methods=METHODS + extra)
    for run in obj["runs"]:
        if run["hparams"] in ({"thr": 0.2, "w": 3.0}, {"alpha": 0.5, "adversary_lr": 2e-4}):
            run["eval"].update(success=0.6, normalized=60.0)
    m = merge([_load(tmp_path, obj, "extra.json")])[Key("toytown", "image", "nocrash", version=2)]
    rows = driving_rows(m)
    assert [(r.method, r.hparams) for r in rows if r.method == "ours-step"] == [("ours-step", {"thr": 0.1, "w": 5.0})]
    assert [r.label for r in rows if r.method == "fca"] == ["FCA (TCA), alpha 0.2, adversary_lr 0.0002",
                                                             "FCA (TCA), alpha 0.5, adversary_lr 0.0002"]
    assert [r.method for r in rows][3:5] == ["fca", "fca"]
    page = report.build([_load(tmp_path, obj, "extra.json")]).text
    assert "| Ours (step) | thr 0.2, w 3 | 5 | 60.0 ± 0.0 |" in page   # in the grid table
    assert "THR 20%" not in _section(page, "## ToyTown (nocrash)")
    # a sweep without the paper's setting: its step settings are Ours' rows
    other = toytown_file(methods=tuple(x for x in METHODS if x[0] != "ours-step") + extra[:1])
    m = merge([_load(tmp_path, other, "other.json")])[Key("toytown", "image", "nocrash", version=2)]
    assert [(r.label, r.hparams) for r in driving_rows(m) if r.method == "ours-step"] == [
        ("Ours (step)", {"thr": 0.2, "w": 3.0})]


def test_the_metric_cells_and_the_wilson_column_are_as_in_table_4(tmp_path):
    table = _section(report.build([_load(tmp_path, toytown_file(), "t.json")]).text, "## ToyTown (nocrash)")
    cells = _cells(table, "BC-OH")
    success = 100 * np.array(SUCCESS["bc-oh"])
    e = stats.mean_interval(success)
    assert cells["success %"] == f"{success.mean():.2f} ± {success.std(ddof=1):.2f} [{e.low:.2f}, {e.high:.2f}]"
    pooled = stats.wilson(round(sum(SUCCESS["bc-oh"]) * EPISODES), SEEDS * EPISODES)
    assert cells["success % of all episodes [Wilson 95%]"] == (f"{100 * pooled.value:.2f} [{100 * pooled.low:.2f}, "
                                                               f"{100 * pooled.high:.2f}]")
    crash = np.array(COLLISIONS["bc-oh"])
    e = stats.mean_interval(crash)
    assert cells["collisions"] == f"{crash.mean():.2f} ± {crash.std(ddof=1):.2f} [{e.low:.2f}, {e.high:.2f}]"


def test_the_verdict_columns_count_seeds_judged_copycat_of_seeds_diagnosed(tmp_path):
    table = _section(report.build([_load(tmp_path, toytown_file(), "t.json")]).text, "## ToyTown (nocrash)")
    verdicts = ("copycat: first verdict", "copycat: controlled verdict")

    def counts(table, label):
        return [_cells(table, label)[v] for v in verdicts]
    assert counts(table, "BC-OH") == ["3/5", "2/5"]
    assert counts(table, "Ours, step THR 10% W 5") == ["1/5", "0/5"]
    assert counts(table, "MINE") == ["0/4", "0/4"]   # seed 0 unreadable: not diagnosed, never counted as 0
    assert counts(table, "BC-SO") == ["0/5", "0/5"]
    # a file without diagnostics shows none
    plain = toytown_file()
    for run in plain["runs"]:
        run.pop("diagnostics")
    table = _section(report.build([_load(tmp_path, plain, "plain.json")]).text, "## ToyTown (nocrash)")
    assert counts(table, "BC-OH") == ["—", "—"]


def test_table_3_lists_every_method_of_a_driving_group(tmp_path):
    m = _group(tmp_path)
    found = loss_rows(m)
    assert [lab for lab, _ in found] == [r.label for r in driving_rows(m)]
    text = report.build([_load(tmp_path, toytown_file(), "t.json")]).text
    losses = text[text.index("Loss analysis (the paper's Table 3)"):]
    rows = [line for line in losses.splitlines()[4:] if line.startswith("| ")]
    assert [x.split(" | ")[0][2:] for x in rows[:len(ORDER)]] == [r.label for r in driving_rows(m)]
    i = [m for m, _ in METHODS].index("palr")   # the fixture's losses: train and val alike
    assert _row(losses, "PALR")[1:] == [f"{0.05 + 0.01 * i:.4f}", f"{0.3 + 0.01 * i:.4f}",
                                        f"{0.02 + 0.001 * i:.4f}"] * 2


def _welch_text(a, b, scale=100.0, fmt=".1f", unit=" points"):
    e = stats.welch_difference(scale * np.array(a), scale * np.array(b))

    def plain(x):
        return f"{x:{fmt}}".replace("-", "−")
    return e, f"{plain(e.value) if e.value < 0 else '+' + plain(e.value)}{unit} [{plain(e.low)}, {plain(e.high)}]"


def test_the_comparison_line_states_the_papers_differences_with_welch_intervals(tmp_path):
    m = _group(tmp_path)
    found = driving_comparisons(m)
    assert [(c.a, c.b, c.metric) for c in found] == [("BC-OH", "BC-SO", "success"), ("Ours", "BC-SO", "success"),
                                                     ("Ours", "BC-OH", "success"), ("Ours", "DAgger", "success"),
                                                     ("Ours", "BC-OH", "collisions")]
    text = report.build([_load(tmp_path, toytown_file(), "t.json")]).text
    line = next(x for x in _section(text, "## ToyTown (nocrash)").splitlines()
                if x.startswith("The paper's comparisons"))
    history, words = _welch_text(SUCCESS["bc-oh"], SUCCESS["bc-so"])
    assert history.low > 0 and found[0].ci.diff == pytest.approx(history.value)
    assert f"BC-OH − BC-SO: {words}: BC-OH higher" in line
    ours, words = _welch_text(SUCCESS["ours-step"], SUCCESS["bc-oh"])
    assert ours.low < 0 < ours.high and f"Ours − BC-OH: {words}: no difference shown at 5 seeds" in line
    dagger, words = _welch_text(SUCCESS["ours-step"], SUCCESS["dagger"])
    assert dagger.high < 0 and f"Ours − DAgger: {words}: Ours lower" in line
    crash, words = _welch_text(COLLISIONS["ours-step"], COLLISIONS["bc-oh"], 1.0, ".2f", "")
    assert f"Collisions per episode: Ours − BC-OH: {words}: no difference shown at 5 seeds." in line


def test_no_verdict_with_fewer_than_two_seeds_and_no_comparison_without_its_arms(tmp_path):
    text = report.build([_load(tmp_path, toytown_file(seeds=1), "one.json")]).text
    line = next(x for x in text.splitlines() if x.startswith("The paper's comparisons"))
    diff = 100 * (SUCCESS["bc-oh"][0] - SUCCESS["bc-so"][0])
    assert f"BC-OH − BC-SO: +{diff:.1f} points, no verdict (fewer than 2 seeds)" in line
    assert "[" not in line.split(": ", 1)[1] and "higher" not in line and "shown" not in line
    few = tuple((m, hp) for m, hp in METHODS if m in ("bc-so", "bc-oh", "bc-full"))
    m = _group(tmp_path, methods=few)
    assert [(c.a, c.b) for c in driving_comparisons(m)] == [("BC-OH", "BC-SO")]
    assert [r.method for r in driving_rows(m)] == ["bc-so", "bc-oh", "bc-full"]


def test_the_figure_is_written_beside_the_others_and_linked_under_the_table(tmp_path):
    files = [_load(tmp_path, toytown_file(p), f"{p}.json") for p in ("nocrash", "nocrash-nospeed")]
    out = tmp_path / "out"
    built = report.build(files, out / "figures", out, out / "docs" / "results")
    names = {"driving-toytown-image-nocrash-v2.png", "driving-toytown-image-nocrash-nospeed-v2.png"}  # from version 2
    assert names <= {p.name for p in built.figures}
    page = built.pages["toytown-image.md"].text
    for protocol, number in (("nocrash", 1), ("nocrash-nospeed", 2)):
        section = _section(page, f"## ToyTown ({protocol}): the supplement's Table {number}")
        link = f"](../../figures/driving-toytown-image-{protocol}-v2.png)"
        assert link in section and section.index(link) > section.index("| BC-full (full state: the ceiling) |")
    path = out / "figures" / "driving-toytown-image-nocrash-v2.png"
    save_png(built.figures[path], path)
    with Image.open(path) as im:
        assert 600 < im.size[0] and 300 < im.size[1] <= MAX_HEIGHT
    fig = driving_figure(merge(files[:1])[Key("toytown", "image", "nocrash", version=2)])
    success, stuck = fig.axes[:2]
    labels = [t.get_text() for t in success.get_yticklabels()]
    assert labels == [r.label for r in driving_rows(merge(files[:1])[Key("toytown", "image", "nocrash", version=2)])]
    assert "success" in success.get_title() and "stuck" in stuck.get_title()
    # the ceiling set apart: its bar hatched below a dashed line
    assert sum(bool(p.get_hatch()) for p in success.patches) == 1
    assert any(line.get_linestyle() == "--" for line in success.get_lines())


def test_a_group_outside_the_driving_family_keeps_table_4(tmp_path):
    brax = toytown_file()
    brax["protocol"] = {**tasks.PROTOCOLS["brax"].settings(None)}
    brax["settings"] = resolve("toytown", "image", protocol="brax", preset="default").to_json()
    m = _group(tmp_path)
    assert driving_table(m) is not None
    (b,) = merge([_load(tmp_path, brax, "brax.json")]).values()
    assert driving_table(b) is None
    assert [lab for lab, _ in loss_rows(b)] == ["BC-SO", "BC-OH", "Ours, step THR 10% W 5"]
    text = report.build([_load(tmp_path, brax, "brax.json")]).text
    assert "(the supplement's Table 4 protocol)" in text and "The paper's comparisons" not in text


def test_pieces_written_before_and_after_the_methods_owned_their_knobs_merge_as_one_sweep():
    """Table 1's seed 0 records the weightings' grids as recipe fields, seed 4 as `settings.knobs`: the same
    settings as resolved, so the report merges them as one sweep split by seeds (and still refuses other settings)."""
    results = pathlib.Path(__file__).resolve().parents[1] / "results"
    old, new = (report.load(results / f"toytown-image-nocrash-default-seeds{k}.json") for k in (0, 4))
    assert "step_grid" in old.settings["recipe"] and "knobs" in new.settings
    assert "step_grid" not in new.settings["recipe"]
    group = report.merge([old, new])[Key("toytown", "image", "nocrash", version=1)]  # before versions: the first
    assert sorted({r["seed"] for r in group.runs if r["method"] == "bc-oh"}) == [0, 4]
    other = report.load(results / "toytown-image-nocrash-default-seeds4.json")
    other.settings["recipe"]["lr"] = 0.5
    with pytest.raises(report.ReportError, match="with other settings"):
        report.merge([old, other])


def test_the_results_page_leads_with_the_driving_verdict_of_the_state_its_figure_and_the_pages(tmp_path):
    """`analysis.driving_verdicts` counts over every state table and quotes the state's Table 1; the results page
    states it after the headline, with that table's figure and a link to each page with driving tables."""
    files = [_load(tmp_path, toytown_file(p, obs=obs), f"{obs}-{p}.json")
             for obs in ("pos", "image") for p in ("nocrash-nospeed", "nocrash")]
    (v,) = driving_verdicts(merge(files))
    assert v.headline == Key("toytown", "pos", "nocrash", version=2)   # Table 1 though Table 2 was loaded first
    assert v.means == pytest.approx({m: 100 * np.mean(SUCCESS[m]) for m in ("bc-so", "bc-oh")})
    history, words = _welch_text(SUCCESS["bc-oh"], SUCCESS["bc-so"])
    assert (v.history.a, v.history.b) == ("BC-OH", "BC-SO") and v.history.ci.diff == pytest.approx(history.value)
    # two state tables of 11 configurations × 5 seeds, MINE's seed 0 unreadable; BC-OH copycat in 3 seeds by the
    # first verdict (Ours in 1) and in 2 by the controlled one
    assert (v.policies, v.copycats, v.judged, v.controlled) == (2 * (len(ORDER) * SEEDS - 1), 2 * 4, 2 * 54, 2 * 2)
    assert v.camera == pytest.approx(100 * np.mean(SUCCESS["dagger"])) and v.perceived is None  # BC-full excluded
    out = tmp_path / "out"
    index = report.build(files, out / "figures", out, out / "docs" / "results").pages["index.md"].text
    section = _section(index, "## Driving: ToyTown")
    assert index.index("## Driving: ToyTown") < index.index("## Every task's page")
    assert f"success BC-OH {v.means['bc-oh']:.1f}%, BC-SO {v.means['bc-so']:.1f}% (BC-OH − BC-SO: {words}" in section
    assert "8 of 108 policies by the first verdict, 4 of 108 by the controlled one" in section
    assert f"learned from pixels, at most {v.camera:.1f}% success in any table" in section
    assert "](../../figures/driving-toytown-nocrash-v2.png)" in section
    assert ("Every driving table: [ToyTown, `pos` observations](toytown-pos.md), "
            "[ToyTown, `image` observations](toytown-image.md).") in section
    # the camera alone gives no verdict: the state is what it quotes
    assert driving_verdicts(merge(files[2:])) == []
    assert "## Driving" not in report.build(files[2:]).pages["index.md"].text
