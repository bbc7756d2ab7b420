"""`experiments.report`: tables built from results files, merged per environment; bad files refused."""

import json

import pytest

from experiments import report


def _results(env="hopper", methods=(("bc-so", {}, 300.0), ("bc-oh", {}, 1000.0),
                                     ("ours-step", {"thr": 0.1, "w": 5.0}, 1500.0),
                                     ("ours-step", {"thr": 0.2, "w": 3.0}, 1600.0),
                                     ("ours-softmax", {"tau": 5.0}, 1200.0)), preset_methods=None):
    runs, summary = [], []
    for method, hp, ret in methods:
        for seed, delta in enumerate((-10.0, 10.0)):
            runs.append({"method": method, "hparams": hp, "seed": seed, "status": "ok", "error": None,
                         "eval": {"episodes": 5, "return_mean": ret + delta, "return_std": 1.0,
                                  "normalized": (ret + delta) / 20},
                         "losses": {s: {"unweighted": 0.1 + seed, "changepoint": 0.3, "copycat": 0.05}
                                    for s in ("train", "val")}})
        summary.append({"method": method, "hparams": hp, "n_seeds": 2, "return_mean": ret, "return_std": 10.0,
                        "normalized_mean": ret / 20, "normalized_std": 0.5})
    return {"schema": 1, "env": env, "obs": "pos", "preset": "default",
            "config": {"iterations": 30000, "seeds": 2, "eval_episodes": 20,
                       "methods": preset_methods or ["bc-so", "bc-oh", "ours-step", "ours-softmax"]},
            "expert": {"return_mean": 2000.0, "return_std": 50.0, "random_return_mean": 0.0},
            "runs": runs, "summary": summary, "timing": {"total_s": 100.0},
            "system": {"jax": "0.9.2", "backend": "cpu", "devices": 1, "commit": "abc1234", "machine": "test CPU"}}


def _write(tmp_path, name, obj):
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return path


def test_the_report_merges_files_per_environment_and_builds_every_table(tmp_path):
    main = _write(tmp_path, "main.json", _results())
    base = _write(tmp_path, "base.json", _results(methods=(("fca", {"alpha": 0.1}, 1100.0),
                                                           ("dagger", {"rounds": 4, "budget": 100}, 1900.0)),
                                                  preset_methods=["fca", "dagger"]))
    text = report.report([report.load(main), report.load(base)])
    state = text[text.index("| method | Hopper |"):]
    assert "| BC-OH | 1,000 ± 10 (50%) |" in state
    assert "| Ours, step THR 10% W 5 | 1,500 ± 10 (75%) |" in state
    assert "| Ours, best step | 1,600 ± 10 (80%) <br>(thr 0.2, w 3) |" in state     # the best, with its setting
    assert "| FCA | 1,100 ± 10 (55%) |" in state and "| DAgger (online) | 1,900 ± 10 (95%) |" in state
    assert "| HistoryDropout | — |" in state                                         # not run: a dash
    # next to the paper: ratios to BC-OH within each source
    assert "| Ours | 641 (2.19×) | 1,500 (1.50×) |" in text
    # provenance: the command is rebuilt from the file, with its commit and machine
    assert "`python -m experiments.sweep --env hopper --obs pos --preset default --seeds 2` " in text
    assert "--methods fca,dagger" in text and "commit `abc1234`" in text and "test CPU" in text
    # the grid marks the best configuration; the loss table averages seeds
    assert "| **DAgger (online)** | rounds 4, budget 100 | 2 | **1,900.0 ± 10.0** | 95.0 |" in text
    assert "| BC-OH | 0.6000 | 0.3000 | 0.0500 | 0.6000 | 0.3000 | 0.0500 |" in text


def test_the_cli_writes_the_report_section_and_keeps_the_rest(tmp_path, capsys):
    main = _write(tmp_path, "main.json", _results())
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\nhand-written prose\n")
    assert report.main([str(main), "--out", str(out)]) == 0
    first = out.read_text()
    assert "hand-written prose" in first and "<!-- report:start -->" in first and "| BC-SO | 300 ± 10 (15%) |" in first
    assert report.main([str(main), "--out", str(out)]) == 0
    assert out.read_text() == first   # regenerating replaces the section, nothing else


@pytest.mark.parametrize("content, message", [
    ("{not json", "not valid JSON"),
    ('{"schema": 1}', "not a sweep results file (missing env"),
    (None, "cannot read"),
])
def test_bad_results_files_are_refused_with_exit_code_2(tmp_path, capsys, content, message):
    path = tmp_path / "r.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(SystemExit) as exc:
        report.main([str(path)])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_the_same_configuration_in_two_files_is_refused(tmp_path, capsys):
    a, b = _write(tmp_path, "a.json", _results()), _write(tmp_path, "b.json", _results())
    with pytest.raises(SystemExit) as exc:
        report.main([str(a), str(b)])
    assert exc.value.code == 2 and "is also in another results file" in capsys.readouterr().err
