"""The prepared accelerator run (`experiments/device/`): its refusals, its measurements at tiny sizes, the smoke run."""

import hashlib
import json
import os
import pathlib
import subprocess
import sys
import tarfile

import numpy as np
import pytest

from experiments.device import measure

ROOT = pathlib.Path(__file__).resolve().parents[1]
RUN = ROOT / "experiments" / "device" / "run.sh"


def _plan_env(tmp_path) -> dict:
    """The environment of a smoke plan run into `tmp_path`: its output, work and cache folders there, this Python,
    no user expert directory (imported experts come from the cache)."""
    env = {**os.environ, "OUT": str(tmp_path / "out"), "WORK": str(tmp_path / "work"), "PYTHON": sys.executable,
           "APE_JAX_CACHE": str(tmp_path / "data")}
    env.pop("APE_JAX_EXPERTS", None)
    return env


def _smoke_plan(tmp_path, plan: str) -> set[str]:
    """Runs `run.sh --smoke --plan PLAN` (it must exit 0) and returns the names packed in its `device.tgz`."""
    out = subprocess.run(["bash", str(RUN), "--smoke", "--plan", plan], capture_output=True, text=True,
                         timeout=1800, env=_plan_env(tmp_path))
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    with tarfile.open(tmp_path / "out" / "device.tgz") as packed:
        return set(packed.getnames())


def test_measure_refuses_a_cpu_without_smoke(tmp_path, capsys):
    if measure.jax.default_backend() == "gpu":
        pytest.skip("this machine has a GPU")
    assert measure.main(["--out", str(tmp_path)]) == 2
    assert "JAX sees no GPU" in capsys.readouterr().err
    assert not (tmp_path / "measure.json").exists()


@pytest.mark.parametrize("argv,message", [(["--seeds", "0"], ">= 1"), (["--out", "/proc/x"], "--out /proc/x")])
def test_measure_refuses_bad_input_with_exit_code_2(argv, message, capsys):
    argv = argv if "--out" in argv else [*argv, "--out", "somewhere"]
    with pytest.raises(SystemExit) as exc:
        measure.main([*argv, "--smoke"])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_grid_throughput_counts_the_paper_grid_and_its_flops():
    g = measure.grid_throughput(iters=3, seeds=2, repeats=1)
    assert g["models"] == 2 * 14  # BC-SO, BC-OH, 6 step, 6 softmax per seed
    assert g["dense_weights"] == 2 * 5 * 300 + 300 * 300 * 2 + 300 * 100 + 100 * 300 + 300 * 3
    assert g["model_updates_s"] > 0
    assert g["flops_s"] == pytest.approx(6 * 128 * g["dense_weights"] * g["model_updates_s"])


def test_the_wheels_list_pins_one_version_of_each_package():
    lines = [ln for ln in (RUN.parent / "wheels.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    names = [ln.split("==")[0].lower().replace("_", "-") for ln in lines]
    assert all("==" in ln for ln in lines) and len(names) == len(set(names))
    assert {"brax", "mujoco", "mujoco-mjx"} <= set(names)


def test_run_sh_refuses_an_unknown_argument():
    out = subprocess.run(["bash", str(RUN), "--fast"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "unknown argument --fast" in out.stderr
    out = subprocess.run(["bash", str(RUN), "--plan", "everything"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "unknown plan 'everything'" in out.stderr


def test_the_fcaexpert_plan_refuses_a_cache_without_fcas_expert_before_anything_runs(tmp_path):
    out = subprocess.run(["bash", str(RUN), "--smoke", "--plan", "fcaexpert"], capture_output=True, text=True,
                         timeout=60, env=_plan_env(tmp_path))
    assert out.returncode == 2 and "FCA's expert is not imported" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and not (tmp_path / "work" / "hopper-pos").exists()


@pytest.mark.slow
def test_run_sh_smoke_measures_and_finishes_both_sweeps(tmp_path):
    env = {**os.environ, "OUT": str(tmp_path / "out"), "WORK": str(tmp_path / "work"), "PYTHON": sys.executable}
    out = subprocess.run(["bash", str(RUN), "--smoke"], capture_output=True, text=True, timeout=1800, env=env)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    m = json.loads((tmp_path / "out" / "measure.json").read_text())
    assert m["smoke"] and m["grid"]["model_updates_s"] > 0 and m["mjx"][0]["steps_s"] > 0
    for stage in ("hopper-pos-paper", "hopper-image-paper"):
        timing = json.loads((tmp_path / "out" / stage / "timings.json").read_text())
        assert timing["finished"] is True, out.stdout[-3000:]
        results = json.loads((tmp_path / "out" / stage / "results.json").read_text())
        assert all(r["status"] == "ok" for r in results["runs"])


@pytest.mark.slow
def test_run_sh_paper_fca_plan_smoke_finishes_both_sweeps_and_packs_them(tmp_path):
    """`--plan paper-fca --smoke`: FCA and FCA-IB on Hopper (8 seeds) and HalfCheetah (3) side by side, packed."""
    names = _smoke_plan(tmp_path, "paper-fca")
    for stage, seeds in (("hopper-pos-paper-fca", 8), ("halfcheetah-pos-paper-fca", 3)):
        assert f"./{stage}/results.json" in names
        results = json.loads((tmp_path / "out" / stage / "results.json").read_text())
        assert {r["method"] for r in results["runs"]} == {"fca", "fca-ib"}
        assert len(results["runs"]) == 2 * seeds and all(r["status"] == "ok" for r in results["runs"])


@pytest.mark.slow
def test_run_sh_images_plan_smoke_finishes_the_three_tasks_both_ways_and_packs_them(tmp_path):
    """`--plan images --smoke`: the MuJoCo-Image grid through each task's pretrained encoder, fine-tuned and frozen
    (frames rendered from the state demonstrations' simulator states), six sweeps side by side, packed."""
    names = _smoke_plan(tmp_path, "images")
    plan = json.loads((tmp_path / "out" / "images" / "plan.json").read_text())
    assert plan["smoke"] and all(s["finished"] for s in plan["sweeps"].values())
    for task in ("hopper", "walker2d", "halfcheetah"):
        for variant, encoder in (("finetune", "perception"), ("frozen", "small")):
            name = f"{task}-{variant}"
            assert f"./images/{name}/results.json" in names
            results = json.loads((tmp_path / "out" / "images" / name / "results.json").read_text())
            assert {r["method"] for r in results["runs"]} == {"bc-so", "bc-oh", "ours-step", "ours-softmax", "fca"}
            assert all(r["status"] == "ok" for r in results["runs"])
            recipe = results["settings"]["recipe"]
            assert recipe["encoder"] == encoder and recipe["perception_training"] == variant
            assert recipe["perception_sha256"] == results["config"]["perception"]["sha256"]
            assert results["protocol"]["frames"] == "states"
            data = results["config"]["data"]
            assert data["path"].endswith(".npz") and f"/{task}-pos-" in data["path"]  # the state dataset's rows
            assert "frames: " in (tmp_path / "out" / "images" / name / "log.txt").read_text()


@pytest.mark.slow
def test_run_sh_fcaexpert_plan_smoke_trains_every_program_on_the_imported_experts_raw_labels(tmp_path):
    """`--plan fcaexpert --smoke`: an expert of the CS294 pickle's structure imported into the carried cache, then
    Table 5's methods (one sweep per program, side by side) on its raw labels, packed."""
    from test_import_expert import _cs294, _write_pickle

    pkl = _write_pickle(tmp_path / "Hopper-v1.pkl", _cs294(np.random.default_rng(0)))
    sha256 = hashlib.sha256(pkl.read_bytes()).hexdigest()
    imported = subprocess.run([sys.executable, "-m", "experiments.import_expert", str(pkl), "--env", "hopper",
                               "--name", "cs294", "--protocols", "mujoco-state"], capture_output=True, text=True,
                              timeout=900, env=_plan_env(tmp_path), cwd=ROOT)
    assert imported.returncode == 0, imported.stderr[-3000:]
    names = _smoke_plan(tmp_path, "fcaexpert")
    name = "hopper-pos-mujoco-state-rows-paper-bn-mlp-cs294-raw"
    for stage, expected in (("bc-so", {"bc-so"}), ("bc-oh", {"bc-oh", "ours-step", "ours-softmax"}),
                            ("bc-full", {"bc-full"}), ("fca", {"fca"})):
        assert f"./{name}-{stage}/results.json" in names
        results = json.loads((tmp_path / "out" / f"{name}-{stage}" / "results.json").read_text())
        assert {r["method"] for r in results["runs"]} == expected
        assert all(r["status"] == "ok" for r in results["runs"])
        assert results["protocol"]["labels"] == "raw" and results["protocol"]["expert"] == "cs294"
        assert results["config"]["data"]["settings"]["expert"]["sha256"] == sha256
    log = (tmp_path / "out" / f"{name}-fca" / "log.txt").read_text()
    assert "(cached: " in log  # the first sweep collected the rows; the others found them
