"""`results/README.md`, the index of the committed results: it lists every file once, its replay commands parse
and resolve to the settings each file records, and it is what `experiments.results_index` writes now."""

import collections
import importlib
import json
import re
import shutil
import subprocess

import pytest

from ape_jax.pipeline import results as results_lib
from experiments import results_index, sweep

RESULTS = results_index.RESULTS


@pytest.fixture(scope="module")
def index():
    return results_index.entries(RESULTS)


def _committed() -> set[str]:
    """The JSON files git tracks under results/ (relative to it); those on disk where git cannot say."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--", "*.json"], cwd=RESULTS, capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return {p.relative_to(RESULTS).as_posix() for p in RESULTS.rglob("*.json")}
    return {p for p in out.stdout.decode().split("\0") if p}


def test_the_index_lists_every_committed_results_file_exactly_once(index):
    committed = _committed()
    assert len(committed) > 50   # the shipped files, not an empty folder
    listed = collections.Counter(re.findall(r"^\| \[`[^`]+`\]\(([^)]+\.json)\) \|",
                                            (RESULTS / "README.md").read_text(), flags=re.M))
    assert {p: n for p, n in listed.items() if n != 1} == {}
    assert committed <= set(listed), f"not in the index: {sorted(committed - set(listed))}"
    assert set(listed) == {e.path for e in index}   # and nothing the folder does not hold


def test_every_sweep_replay_parses_and_resolves_to_the_settings_its_file_records(index):
    sweeps = [e for e in index if e.kind == "sweep"]
    assert len(sweeps) > 50
    for e in sweeps:
        r = results_lib.load(RESULTS / e.path)
        if not e.from_settings:   # no arguments give its settings: said so, with its command as recorded
            assert "no arguments give its settings" in e.cells[-1], e.path
            assert e.command is None or not {"--resume", "--out"} & set(e.command), e.path
            continue
        assert e.command[:3] == ["python", "-m", "experiments.sweep"] and "--resume" not in e.command, e.path
        argv = e.command[3:]
        out = argv[argv.index("--out") + 1]
        assert out == f"runs/replay/{e.path.removesuffix('.json')}", e.path   # a new folder, one per file
        args = sweep.parse(argv, writes=False)   # parse only: nothing runs
        recorded = r.records()
        for section in ("protocol", "budget", "recipe"):
            assert getattr(args.settings, section) == getattr(recorded, section), (e.path, section)
        ran = set(args.methods)   # the methods' own settings: those of the methods it ran
        assert {m: k for m, k in args.settings.knobs.items() if m in ran} == \
            {m: k for m, k in recorded.knobs.items() if m in ran}, e.path
        assert (args.env, args.obs, args.methods) == (r.env, r.obs, tuple(r.config["methods"])), e.path
        assert args.settings.smoke == bool(r.config.get("smoke")), e.path


def test_every_other_tools_replay_parses_with_that_tools_own_parser(index):
    tools = [e for e in index if e.kind == "tool"]
    assert tools, "the probes of results/exploratory/probes are indexed as pose_probe's outputs"
    for e in tools:
        assert e.command[:2] == ["python", "-m"] and "--resume" not in e.command, e.path
        argv = e.command[3:]
        assert argv.count("--out") == 1 and argv[argv.index("--out") + 1] == f"runs/replay/{e.path}", e.path
        importlib.import_module(e.command[2]).parse(argv)   # exits 2 on an argument it refuses


def test_the_committed_index_is_what_the_generator_writes_now():
    assert results_index.main(["--check"]) == 0


def test_a_piece_of_a_sweep_split_by_seeds_replays_its_seeds_and_a_stale_index_is_caught(tmp_path, monkeypatch,
                                                                                        capsys):
    name = "hopper-pos-fca-rows-default-fca-bc.json"
    obj = json.loads((RESULTS / name).read_text())
    seeds = obj["settings"]["budget"]["seeds"]
    for first in (0, seeds):   # two pieces: the same sweep from seed 0 and from seed `seeds`
        obj["settings"]["budget"]["first_seed"] = first
        (tmp_path / name.replace(".json", f"-seeds{first}.json")).write_text(json.dumps(obj))
    (tmp_path / "queue").mkdir()
    (tmp_path / "queue" / "notes.json").write_text("[1, 2]")   # neither a results file nor a tool's output
    shutil.copy(RESULTS / "exploratory" / "probes" / "hopper-bc-state-h2.json", tmp_path / "queue" / "probe.json")
    found = {e.path: e for e in results_index.entries(tmp_path)}
    late = found[name.replace(".json", f"-seeds{seeds}.json")]
    assert late.cells[6] == f"{seeds} (seeds {seeds}–{2 * seeds - 1})"
    assert found[name.replace(".json", "-seeds0.json")].cells[6] == f"{seeds} (seeds 0–{seeds - 1})"
    args = sweep.parse(late.command[3:], writes=False)
    assert (args.settings.budget.first_seed, args.settings.budget.seeds) == (seeds, seeds)
    assert found["queue/notes.json"].kind == "other" and found["queue/notes.json"].command is None
    assert found["queue/probe.json"].kind == "tool"
    # the folder's index: written, then current; a file added makes it stale (one line, exit 1)
    monkeypatch.setattr(results_index, "RESULTS", tmp_path)
    assert results_index.main([]) == 0 and results_index.main(["--check"]) == 0
    text = (tmp_path / "README.md").read_text()
    assert "## `results/queue/`" in text and text.count("| [`") == 4
    shutil.copy(RESULTS / name, tmp_path / name)
    capsys.readouterr()
    assert results_index.main(["--check"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not current; run python -m experiments.results_index" in err


def test_a_recorded_command_loses_its_resume_and_its_machine_folder():
    cmd = ["python", "-m", "experiments.sweep", "--env", "hopper", "--out", "/work/runs/t5/x", "--resume",
           "--out=/elsewhere", "--fresh", "--seeds", "2"]
    assert results_index.without_output(cmd) == ["python", "-m", "experiments.sweep", "--env", "hopper", "--seeds",
                                                 "2"]
