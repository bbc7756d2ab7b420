"""Several processes, one grid (`jax.distributed`): the same numbers as one process, and only process 0 writes.

Two CPU processes on 127.0.0.1 with two devices each train a grid sharded over
all four devices, and one process with four devices trains the same grid: the
same per-device program (two of the eight padded rows on each device, no
communication inside it). On the 2-core AMD EPYC the parameters come out bit for
bit the same, but XLA:CPU's rounding can depend on how many devices a process
has (a one-device program in a process with four forced devices already
differs in its last bits there), so they are compared as `tests/_compare.py`
compares two trainings of one model. The sweep's command line runs over two
processes on the ToyCar sandbox (no MJX compile); its refusals of bad process
flags are checked without starting JAX.
"""

import json
import os
import pathlib
import socket
import subprocess
import sys

import numpy as np
import pytest

from _compare import UPDATE_RTOL, update_mismatch
from experiments import sweep
from test_learner import LOSS_RTOL

pytestmark = pytest.mark.integration  # end-to-end sweeps: `pytest -m integration`, which CI runs

ROOT = pathlib.Path(__file__).resolve().parents[1]

# Trains a 6-configuration grid through the sweep's `train_program` (padded to 8 rows over 4 devices), then
# again, resumed from process 0's checkpoint at iteration 3 of 6 (the other process has none); process 0 saves
# what both runs trained.
WORKER = """
import pathlib, sys
import jax
pid, count, port, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], pathlib.Path(sys.argv[4])
if count > 1:
    jax.distributed.initialize(f"127.0.0.1:{port}", num_processes=count, process_id=pid)
import jax.numpy as jnp
import numpy as np
sys.path.insert(0, str(pathlib.Path.cwd() / "tests"))
from test_learner import _dataset, GRID
from ape_jax.grid import differing_processes, from_process_zero
from ape_jax.learner import LearnerConfig, make_train, stack_hparams
from ape_jax.pipeline.checkpoint import ProgramCheckpoint
from ape_jax.pipeline.sweep import Program, Run, train_program


assert jax.device_count() == 4 and jax.process_count() == count, (jax.devices(), jax.process_count())


class SavesAtThree(ProgramCheckpoint):
    # as if killed after its save at iteration 3, with the parameters halved: a run resumed from it differs

    def save(self, iteration, state, curves):
        if iteration == 3:
            super().save(iteration, state.replace(params=jax.tree.map(lambda p: p * 0.5, state.params)), curves)


cfg = LearnerConfig(obs_shape=(4,), action_dim=2, iterations=6, batch_size=32)
program = Program("grid", cfg, tuple(Run("grid-test", {"i": float(i)}, 0) for i in range(6)), make_train(cfg))
hparams, data = stack_hparams(GRID + GRID), _dataset()
writes = jax.process_index() == 0
if writes:
    out.mkdir(parents=True, exist_ok=True)
first = SavesAtThree(out / "ckpt", every=3) if writes else None
params, metrics, _ = train_program(program, hparams, None, data, lambda n: None, chunk=3, checkpoint=first)
again = ProgramCheckpoint(out / "ckpt", every=3) if writes else None
resumed, resumed_metrics, _ = train_program(program, hparams, None, data, lambda n: None, chunk=3, checkpoint=again)
assert again is None or again._last_saved == 6  # it did resume from 3, and saved at the end

# process 0's values arrive bit for bit: the sign of -0.0, NaN, 64-bit integers
mine = {"f": np.array([-0.0, np.nan, 1.5], np.float32) if writes else np.ones(3, np.float32),
         "i": np.array([2**40 + pid], np.int64)}
got = from_process_zero(mine)
assert got["f"].tobytes() == np.array([-0.0, np.nan, 1.5], np.float32).tobytes() and got["i"][0] == 2**40, got
assert differing_processes(data) == [] and differing_processes(mine) == ([1] if count > 1 else [])

if writes:
    keys = jnp.stack([r.key for r in program.runs])
    init = jax.jit(jax.vmap(lambda k: program.learner.init(k, GRID[0], data).params))(keys)
    flat = {f"init/{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(init))}
    flat |= {f"params/{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(params))}
    flat |= {f"resumed/{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(resumed))}
    flat |= {f"metrics/{k}": np.asarray(v) for k, v in metrics.items()}
    flat |= {f"resumed_metrics/{k}": np.asarray(v) for k, v in resumed_metrics.items()}
    np.savez(out / "trained.npz", **flat)
print("process", pid, "of", count, "done", type(jax.tree.leaves(params)[0]).__name__)
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def env_with(devices: int) -> dict:
    """This environment (the suite's XLA flags and compilation cache included) with `devices` CPU devices."""
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()
    return {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": flags, "PYTHONPATH": str(ROOT)}


def run_processes(commands: list[list[str]], env: dict, timeout: float = 300) -> list[subprocess.CompletedProcess]:
    """`commands` started together (one process each), waited for; all killed if one outlives `timeout`."""
    procs = [subprocess.Popen(c, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for c in commands]
    try:
        outs = [p.communicate(timeout=timeout) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    return [subprocess.CompletedProcess(c, p.returncode, o, e) for c, p, (o, e) in zip(commands, procs, outs)]


def test_two_processes_train_the_grid_like_one_process_and_resume_from_process_zero(tmp_path):
    code = WORKER
    port = free_port()
    two = run_processes([[sys.executable, "-c", code, str(i), "2", str(port), str(tmp_path / "two")]
                         for i in range(2)], env_with(2))
    for i, done in enumerate(two):
        assert done.returncode == 0, (i, done.stderr[-3000:])
        assert f"process {i} of 2 done ndarray" in done.stdout  # outputs came back to every host, whole
    [one] = run_processes([[sys.executable, "-c", code, "0", "1", "0", str(tmp_path / "one")]], env_with(4))
    assert one.returncode == 0, one.stderr[-3000:]

    a, b = np.load(tmp_path / "two" / "trained.npz"), np.load(tmp_path / "one" / "trained.npz")
    assert sorted(a.files) == sorted(b.files) and a["metrics/loss"].shape == (6, 6)
    for run in ("metrics", "resumed_metrics"):
        for k in (k for k in a.files if k.startswith(f"{run}/")):
            np.testing.assert_allclose(a[k], b[k], rtol=LOSS_RTOL, err_msg=k)
    n = len([k for k in a.files if k.startswith("init/")])
    for i in range(6):  # each row, process 1's devices' rows 4 and 5 included
        init = [a[f"init/{j}"][i] for j in range(n)]
        for run in ("params", "resumed"):
            mine, reference = ([x[f"{run}/{j}"][i] for j in range(n)] for x in (a, b))
            assert update_mismatch(mine, reference, init) < UPDATE_RTOL, (run, i)
    # the second run resumed from the (halved) saved state: its first three iterations are the saved curves, the
    # rest differ; a row that had not (on process 1's devices: the state comes from process 0) would differ from
    # the one-process run's by about its whole update, a hundred times the tolerance above
    loss, resumed = a["metrics/loss"], a["resumed_metrics/loss"]
    assert np.array_equal(loss[:, :3], resumed[:, :3]) and np.all(loss[:, 3:] != resumed[:, 3:])
    assert np.all(np.isfinite(loss)) and len(set(loss[:, -1])) == 6  # six runs, each its own


SWEEP = ["--env", "toycar", "--obs", "full", "--iterations", "4", "--eval-episodes", "1", "--seeds", "1",
         "--methods", "bc-oh,ours-softmax", "--softmax-grid", "0.5,1", "--quiet",
         "--set", "budget.probe_steps=0"]  # no copycat diagnostics (process 0 evaluates alone; test_diagnostics)


def test_a_sweep_over_two_processes_is_written_by_process_zero_alone(tmp_path):
    port = free_port()

    def both():
        return run_processes([[sys.executable, "-m", "experiments.sweep", *SWEEP, "--coordinator", f"127.0.0.1:{port}",
                               "--num-processes", "2", "--process-id", str(i),
                               # each process its own --out and data cache: process 1 must create neither
                               "--out", str(tmp_path / f"out{i}"), "--data-dir", str(tmp_path / f"data{i}")]
                              for i in range(2)], env_with(2))

    first = both()
    for i, done in enumerate(first):
        assert done.returncode == 0, (i, done.stderr[-3000:])
    assert "process 1 of 2: trained its share of the grid" in first[1].stdout
    results = json.loads((tmp_path / "out0" / "results.json").read_text())
    assert len(results["runs"]) == 3 and all(r["status"] == "ok" for r in results["runs"])
    assert (tmp_path / "out0" / "params" / "h2").is_dir() and (tmp_path / "data0").is_dir()
    assert not (tmp_path / "out1").exists() and not (tmp_path / "data1").exists()

    again = both()  # finished: process 0 reports it, and the other stops with it instead of waiting to train
    assert [done.returncode for done in again] == [0, 0], again[1].stderr[-3000:]
    assert "already holds this sweep" in again[0].stdout and "trained" not in again[1].stdout
    assert not (tmp_path / "out1").exists()


def test_a_method_that_reads_another_s_policies_is_refused_over_two_processes_before_any_work(tmp_path):
    port = free_port()
    done = run_processes([[sys.executable, "-m", "experiments.sweep", "--env", "toycar", "--obs", "full", "--smoke",
                           "--methods", "bc-so,priming", "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
                           "--process-id", str(i), "--out", str(tmp_path / "out"), "--data-dir", str(tmp_path / "data")]
                          for i in range(2)], env_with(1))
    assert [d.returncode for d in done] == [2, 2], done[0].stderr[-2000:]
    assert "priming reads bc-so's trained policies, which a multi-process sweep does not gather" in done[0].stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "data").exists()   # nothing collected or written


@pytest.mark.parametrize("flags, message", [
    (["--num-processes", "0", "--process-id", "0", "--coordinator", "127.0.0.1:1234"], "--num-processes must be >= 1"),
    (["--num-processes", "2", "--process-id", "2", "--coordinator", "127.0.0.1:1234"], "must be in [0, 2), got 2"),
    (["--num-processes", "2", "--process-id", "-1", "--coordinator", "127.0.0.1:1234"], "--process-id must be in"),
    (["--num-processes", "2", "--process-id", "0", "--coordinator", "127.0.0.1"], "is not HOST:PORT"),
    (["--num-processes", "2", "--process-id", "0", "--coordinator", ":1234"], "is not HOST:PORT"),
    (["--num-processes", "2", "--process-id", "0", "--coordinator", "host:http"], "is not HOST:PORT"),
    (["--num-processes", "2", "--process-id", "0", "--coordinator", "host:70000"], "is not HOST:PORT"),
    (["--num-processes", "2"], "--num-processes without --coordinator and --process-id"),
    (["--coordinator", "127.0.0.1:1234", "--process-id", "1"], "without --num-processes: give all three"),
    (["--num-processes", "two"], "invalid int value"),
])
def test_bad_process_flags_are_refused_before_jax_starts(flags, message, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        sweep.main(["--env", "toycar", "--obs", "full", "--out", str(tmp_path / "run"), *flags])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "Traceback" not in err, err
    assert not (tmp_path / "run").exists()


def test_a_coordinator_address_jax_cannot_complete_is_one_line_and_exit_2(tmp_path):
    """JAX_COORDINATOR_ADDRESS outside a cluster JAX detects: JAX has no process count; refused, not a traceback."""
    env = {**env_with(1), "JAX_COORDINATOR_ADDRESS": "127.0.0.1:1234"}
    done = subprocess.run([sys.executable, "-m", "experiments.sweep", "--env", "toycar", "--obs", "full",
                           "--out", str(tmp_path / "run")], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2 and "jax.distributed.initialize" in done.stderr, done.stderr[-2000:]
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


def test_one_process_given_as_flags_is_the_plain_sweep():
    procs = sweep._distributed.start(sweep.PROG, ["--coordinator", "127.0.0.1:1234", "--num-processes", "1",
                                                  "--process-id", "0"])
    assert procs == sweep._distributed.Processes() and procs.writes
    assert procs.agree(None, {"any": 1}) is None and procs.agree(0, None) == 0


# Makes and steps Hopper (MJX) in each process: MJX puts its model on the global first device, which is process 0's
MJX_WORKER = """
import sys
import jax
pid, port = int(sys.argv[1]), sys.argv[2]
if pid >= 0:
    jax.distributed.initialize(f"127.0.0.1:{port}", num_processes=2, process_id=pid)
import numpy as np
import envs
env = envs.make("hopper", obs="pos")
state = jax.jit(env.reset)(jax.random.PRNGKey(0))
step = jax.jit(env.step)
for _ in range(5):
    state = step(state, jax.numpy.full(3, 0.3))
print(np.asarray(state.obs).tobytes().hex())
"""


def test_an_mjx_task_steps_in_every_process_of_a_multi_process_run_as_in_one_process():
    port = free_port()
    done = run_processes([[sys.executable, "-c", MJX_WORKER, str(i), str(port)] for i in range(2)], env_with(1))
    for i, d in enumerate(done):
        assert d.returncode == 0, (i, d.stderr[-3000:])   # process 1 could not close over process 0's model
    alone = subprocess.run([sys.executable, "-c", MJX_WORKER, "-1", "0"], cwd=ROOT, env=env_with(1),
                           capture_output=True, text=True, timeout=300)
    assert alone.returncode == 0, alone.stderr[-3000:]
    assert done[0].stdout.split()[-1] == done[1].stdout.split()[-1] == alone.stdout.split()[-1]


# Process 0 "evaluates" for DELAY seconds before it releases the others (or dies without releasing them); process 1
# waits for it as the sweep's other processes do, then both end through JAX's shutdown barrier
WAIT_WORKER = """
import os, sys, time
import jax
pid, port, mode = int(sys.argv[1]), sys.argv[2], sys.argv[3]
from experiments import _distributed
procs = _distributed.start("test", ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
                                    "--process-id", str(pid)])
t0 = time.monotonic()
if procs.writes:
    time.sleep(3)
    if mode == "dies":
        os._exit(3)
    procs.release()
    print("released")
else:
    code = procs.wait_for_writer()
    print(f"waited {time.monotonic() - t0:.1f} s, code {code}")
    sys.exit(code)
"""


def test_the_other_processes_wait_for_process_zero_to_release_them_and_end_with_it():
    port = free_port()
    done = run_processes([[sys.executable, "-c", WAIT_WORKER, str(i), str(port), "releases"] for i in range(2)],
                         env_with(1), timeout=120)
    assert [d.returncode for d in done] == [0, 0], [d.stderr[-2000:] for d in done]
    waited = float(done[1].stdout.split()[1])
    assert waited >= 2.5 and done[1].stdout.strip().endswith("code 0") and "released" in done[0].stdout


def test_a_process_whose_writer_dies_ends_too_instead_of_waiting_its_day():
    """Process 0 dies without releasing the other: the coordination service goes with it, and the waiting process
    ends within the test's minutes, not after the wait's day: JAX's client aborts it, or (first, under load) its
    wait fails at once and returns 1 (`wait_for_writer`), before the abort."""
    port = free_port()
    done = run_processes([[sys.executable, "-c", WAIT_WORKER, str(i), str(port), "dies"] for i in range(2)],
                         env_with(1), timeout=400)
    assert done[0].returncode == 3 and done[1].returncode != 0
    if "waited" in done[1].stdout:   # "waited 3.0 s, code 1": the failed wait's return, seconds after the death
        waited, code = done[1].stdout.split()[1], done[1].stdout.split()[-1]
        assert float(waited) < 60 and code == "1", done[1].stdout
