"""The report's figures read on a page: no figure taller than `MAX_HEIGHT` pixels, no title drawn over a panel or out
of the picture, one figure per family of groups, and a results file of one seed per configuration drawn whole."""

import json
import math
import pathlib

import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.transforms import Bbox

from experiments import report
from experiments.report import figures

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _overlap(a: Bbox, b: Bbox, slack: float = 4.0) -> bool:
    """Whether two boxes (pixels) share more than a `slack`-pixel strip: edges that touch (constrained layout leaves
    text a pixel or two from the panel it labels) are not an overlap."""
    return min(a.x1, b.x1) - max(a.x0, b.x0) > slack and min(a.y1, b.y1) - max(a.y0, b.y0) > slack


def layout_faults(fig: Figure) -> list[str]:
    """What is drawn where it cannot be read, after a draw (constrained layout runs in it): a figure-level text
    (title, footnote) or legend over a panel or outside the picture, two panels (each with its title, labels and
    ticks) over one another, a panel outside the picture."""
    canvas = FigureCanvasAgg(fig)   # the canvas `save_png` renders with
    canvas.draw()
    renderer = canvas.get_renderer()
    frame = fig.bbox.padded(1.0)
    panels = [(ax.get_title() or f"axes {i}", ax.get_tightbbox(renderer)) for i, ax in enumerate(fig.axes)
              if ax.get_visible()]
    faults = []
    for i, (name, box) in enumerate(panels):
        if not (frame.contains(box.x0, box.y0) and frame.contains(box.x1, box.y1)):
            faults.append(f"panel {name!r} reaches outside the figure")
        faults += [f"panels {name!r} and {other!r} overlap" for other, box2 in panels[i + 1:] if _overlap(box, box2)]
    for artist in [*fig.texts, *fig.legends]:
        if not artist.get_visible() or (hasattr(artist, "get_text") and not artist.get_text()):
            continue
        box = artist.get_window_extent(renderer)
        name = artist.get_text() if hasattr(artist, "get_text") else "the figure's legend"
        if not (frame.contains(box.x0, box.y0) and frame.contains(box.x1, box.y1)):
            faults.append(f"{name[:40]!r} reaches outside the figure")
        faults += [f"{name[:40]!r} is drawn over panel {p!r}" for p, pbox in panels if _overlap(box, pbox)]
    return faults


def _height(fig: Figure) -> float:
    """The figure's height in pixels as `save_png` writes it."""
    return fig.get_size_inches()[1] * figures.DPI


@pytest.fixture(scope="module")
def committed():
    """The report's figures over the committed `results/*.json` (`build` draws them; nothing is written)."""
    files = [report.load(path) for path in sorted((ROOT / "results").glob("*.json"))]
    return report.build(files, ROOT / "figures", ROOT, ROOT / "docs" / "results").figures


def test_every_committed_figure_fits_a_screen_and_draws_no_title_over_a_panel(committed):
    assert committed, "the committed results draw no figure"
    tall = {p.name: round(_height(f)) for p, f in committed.items() if _height(f) > figures.MAX_HEIGHT + 0.5}
    assert tall == {}, f"taller than {figures.MAX_HEIGHT} px at {figures.DPI} dpi: {tall}"
    faults = {p.name: f for p, fig in committed.items() if (f := layout_faults(fig))}
    assert faults == {}


def test_the_returns_figures_are_one_per_family_and_the_budget_figure_draws_the_verdicts_thresholds(committed):
    names = sorted(p.name for p in committed)
    assert "returns.png" not in names and "curves.png" not in names and "weights.png" not in names
    assert [n for n in names if n.startswith("returns-")] == sorted(
        f"returns-{name}.png" for name, _ in figures.FAMILIES)   # the committed results have a group in each
    fig = committed[ROOT / "figures" / "paper-budget.png"]
    ylabels = [ax.get_ylabel() for ax in fig.axes]
    columns = list(dict.fromkeys(ax.get_title() for ax in fig.axes))   # the three tasks, then FCA's expert's
    assert columns[:3] == ["Hopper", "HalfCheetah", "Walker2d"] and "Hopper (FCA's expert, raw labels)" in columns
    for measure in ("% of expert", "embedding ratio", "control ratio", "predictability ratio"):
        assert sum(label.startswith(measure) for label in ylabels) == len(columns), (measure, ylabels)   # a column each
    t = figures.verdict_thresholds()
    for ax in fig.axes:
        ref = {line.get_ydata()[0] for line in ax.get_lines() if line.get_linestyle() == "--"}
        want = {"embedding": t["embedding_ratio"], "control": t["control_ratio"],
                "predictability": t["predictability_ratio"]}
        expected = next((v for k, v in want.items() if ax.get_ylabel().startswith(k)), None)
        assert ref == (set() if expected is None else {expected}), (ax.get_ylabel(), ref)
    assert (t["control_ratio"], t["embedding_ratio"]) == (0.25, 0.5)   # ape_jax.diagnostics.THRESHOLDS


def test_the_layout_check_catches_a_title_over_a_panel():
    fig = Figure(figsize=(4, 3), dpi=figures.DPI)   # matplotlib's default layout: nothing moves out of the way
    for ax in fig.subplots(2, 2).ravel():
        ax.set_title("a title far too long for its panel")
    fig.suptitle("a suptitle over the first row's titles")
    faults = layout_faults(fig)
    assert any("drawn over panel" in f for f in faults), faults
    assert any(" overlap" in f for f in faults) and any("outside the figure" in f for f in faults), faults
    narrow = Figure(figsize=(3, 2), dpi=figures.DPI, layout="constrained")
    narrow.subplots()
    narrow.suptitle("a one-line suptitle much wider than the figure it titles")
    assert any("reaches outside the figure" in f for f in layout_faults(narrow))


def test_bars_take_a_missing_or_undefined_sd_as_no_error_bar():
    panel = figures.Bars("one seed", "% of expert", [50.0, None, 20.0, math.nan], [None, None, math.nan, None],
                         [[50.0], [], [20.0], []], ["", "", "", ""], 100.0, "expert")
    fig = figures.bars(["A", "B", "C", "D"], [panel], "one seed per method")
    low, high = fig.axes[0].get_xlim()
    assert math.isfinite(low) and math.isfinite(high) and high > 100
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert texts.count("not run") == 2 and "50" in texts and "20" in texts
    assert layout_faults(fig) == []


def test_fit_rows_keeps_a_figure_under_the_height_by_shrinking_rows_then_adding_columns():
    cols, rows, row_in = figures.fit_rows(6, 4, 3.6, 0.5, 2.4)
    assert (cols, rows, row_in) == (3, 2, 3.6)                                # 3 + 3, not 4 + 2
    cols, rows, row_in = figures.fit_rows(40, 4, 3.6, 0.5, 2.4)
    assert rows * row_in + 0.5 <= figures.MAX_HEIGHT / figures.DPI + 1e-9 and row_in >= 2.4 and cols > 4


def _one_seed_file(tmp_path) -> pathlib.Path:
    """A committed results file (Hopper under the paper's protocol and recipe) cut to its first seed, as a `quick`
    sweep writes one: one seed per configuration, its summary's sd None."""
    obj = json.loads((ROOT / "results" / "hopper-pos-fca-rows-default-fca-bc.json").read_text())
    first = min(r["seed"] for r in obj["runs"])
    obj["runs"] = [r for r in obj["runs"] if r["seed"] == first]
    for row in obj["summary"]:
        run = next(r for r in obj["runs"] if (r["method"], r["hparams"]) == (row["method"], row["hparams"]))
        row.update(n_seeds=1, return_mean=run["eval"]["return_mean"], normalized_mean=run["eval"]["normalized"],
                   return_std=None, normalized_std=None)
    obj["config"]["seeds"] = 1
    path = tmp_path / "results.json"
    path.write_text(json.dumps(obj))
    return path


def test_a_results_file_of_one_seed_per_configuration_gives_a_report_with_its_figures(tmp_path, capsys):
    path = _one_seed_file(tmp_path)
    out = tmp_path / "report.md"
    assert report.main([str(path), "--out", str(out)]) == 0
    drawn = sorted(p.name for p in (tmp_path / "figures").iterdir())
    assert "returns-default.png" in drawn and "curves-default.png" in drawn and any(
        n.startswith("grid-hopper") for n in drawn), drawn
    index = (tmp_path / "docs" / "results" / "index.md").read_text()
    assert "](../../figures/returns-default.png)" in index
    built = report.build([report.load(path)], tmp_path / "again")
    for p, fig in built.figures.items():
        assert _height(fig) <= figures.MAX_HEIGHT and layout_faults(fig) == [], p.name
    grid = next(f for p, f in built.figures.items() if p.name.startswith("grid-"))
    assert "1 seed: no sd" in grid.texts[0].get_text() and "nan" not in grid.texts[0].get_text()


def test_a_legend_entry_names_a_method_once_with_what_differs_per_task():
    from experiments.report.figures.copycat import _one_label

    tau = ["Ours, softmax τ 0.2", "Ours, softmax τ 0.1", "Ours, softmax τ 0.2"]
    assert _one_label(tau) == "Ours, softmax τ 0.2 / 0.1"
    assert _one_label(["FCA (TCA)", "FCA (TCA)", "FCA (TCA), α 0.1"]) == "FCA (TCA) / α 0.1"
    assert _one_label(["BC-OH", "BC-OH"]) == "BC-OH"
