"""The MuJoCo-Image grid on one device, from the pretrained perception encoders, sized to a time limit:
`python -m experiments.device.images`.

    python -m experiments.device.images --limit-s 480 --dry-run   # the plan and its estimate; nothing runs
    python -m experiments.device.images --limit-s 480             # on the GPU (`run.sh --plan images` runs this)
    python -m experiments.device.images --smoke                   # the same at a smoke run's sizes, on a CPU

The grid: Hopper, Walker2d and HalfCheetah from each task's shipped perception encoder (`envs/perception/TASK.npz`,
`recipe.perception=task`, docs/perception.md) at its image size (32×32), the `brax` protocol and the `default`
image preset's data (100 expert episodes, 80 training), BC-SO, BC-OH, ours (step 10% × 5; softmax at the
supplement's τ: Hopper and Walker2d 0.2, HalfCheetah 0.1) and FCA (the supplement's α: Hopper 0.1, the others
0.5), 3 seeds: 15 models a task and variant. Two variants per task, side by side in the same run and at the same
iterations (six sweeps on the one device):
- `finetune`: the paper's setting, the pretrained encoder starting each policy's image encoder and trained end
  to end with it (`recipe.perception_training=finetune`, `models.PerceptionPolicy`);
- `frozen`: the baseline, the encoder fixed and the policies trained on its embeddings (the CPU table's setting,
  `results/TASK-image-default-perceived-*.json`).
Each program's models train as one block (`budget.width`); bfloat16 on a GPU (`recipe.dtype`), float32 elsewhere.

The demonstrations are collected beforehand on the CPU, as state datasets (small enough to carry), and their
frames are rendered on the device from the rows' simulator states (`protocol.frames=states`), so the image runs
train on the rows the CPU collected. On this machine, for each task:

    APE_JAX_CACHE=.devdata python -m experiments.collect --env hopper --obs pos --protocol brax --episodes 100

The budget: the paper's 300,000 iterations, or the most that fits the limit by the estimate, a multiple of the
preset's 1,000-iteration chunk (the plan says which; each results file records `budget.iterations`). The
estimate, made before anything compiles:
- training: the grid's model updates ÷ the device's rate, `--rate` model-updates/s, or the prior: the FLOP/s
  ResNet-18 reached on the H200 (`PRIOR_FLOPS`) over XLA's count of one fine-tuning update
  (`experiments.bench_images.update_flops`), but no more than `PRIOR_SMALL_RATE`, what the H200 gave the small
  FCA networks (launch latency, not arithmetic, bounds so small a model); a frozen model's update is counted as
  a fine-tuning one (it costs less);
- evaluation and the demonstrations' frames: policy-steps and frames ÷ `PRIOR_STEPS` (rendering included);
- `PRIOR_FIXED_S` for the processes' start and compilation, which overlap.

Refused before anything compiles, exit 2 and one line: a plan whose estimate exceeds `--limit-s` (with
`--iterations`, or when not even one chunk fits), a task whose state demonstrations are not in the cache
(`APE_JAX_CACHE`), bfloat16 where the backend has none, an unwritable `--out`.

Writes `OUT/plan.json` (the plan, the estimate, each sweep's wall time and exit status) and, per task and variant,
`OUT/<env>-<variant>/results.json`, `results.csv` and `log.txt`; checkpoints go under `--work`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import subprocess
import sys
import time

from experiments._cli import Parser, fail, unwritable

TASKS = ("hopper", "walker2d", "halfcheetah")
METHODS = ("bc-so", "bc-oh", "ours-step", "ours-softmax", "fca")
# the supplement's softmax temperature and FCA's α per task (its Table 5 and §4)
TAU = {"hopper": 0.2, "walker2d": 0.2, "halfcheetah": 0.1}
ALPHA = {"hopper": 0.1, "walker2d": 0.5, "halfcheetah": 0.5}
VARIANTS = ("finetune", "frozen")   # the paper's setting, and the baseline beside it in the same run
SEEDS = 3
PAPER_ITERATIONS = 300_000
# Priors of the estimate, per backend. FLOP/s: the H200's ResNet-18 at 128×128 (issue 18's run: 176 model-updates/s
# × 409.7 GFLOP per update, `update_flops("resnet18", 128)`), float32; on a CPU, this 2-core machine's drq at 84×84
# (1.66 model-updates/s × 34.0 GFLOP, `python -m experiments.bench_images --encoders drq@84 --no-eval`).
# Small models' ceiling: the H200 trained 16 FCA models of 300,000 updates in 219 s (`run.sh --plan paper-fca`,
# 2026-12-04), ~22,000 model-updates/s; none on a CPU (its FLOP/s bound them).
# Policy-steps (or frames) per second with rendering: on a GPU a guess, ~1/20 of MJX's Hopper steps/s at batch
# 1,024; on a CPU measured at 84×84 (`experiments.bench_images --encoders drq@84`'s evaluation line; 32×32 frames
# through the encoder run faster, so the prior errs long).
PRIOR_FLOPS = {"gpu": 176 * 409.7e9, "cpu": 1.66 * 34.0e9}
PRIOR_SMALL_RATE = {"gpu": 16 * 300_000 / 219, "cpu": math.inf}
PRIOR_STEPS = {"gpu": 5e4, "cpu": 150.0}
PRIOR_FIXED_S = {"gpu": 150.0, "cpu": 600.0}
MARGIN_S = 20.0  # copying the results, the processes' exit


@dataclasses.dataclass(frozen=True)
class Plan:
    """The sweeps to run and what they cost by the estimate."""

    iterations: int
    chunk: int
    models: int              # configurations × seeds, all tasks
    seeds: int
    rate: float              # model-updates/s of the device, all sweeps together
    train_s: float
    eval_s: float
    frames_s: float
    fixed_s: float
    argv: dict[str, list[str]]  # per task, the sweep's arguments
    smoke: bool = False

    @property
    def total_s(self) -> float:
        return self.fixed_s + self.train_s + self.eval_s + self.frames_s

    def describe(self, limit_s: float) -> str:
        paper = "the paper's budget" if self.iterations == PAPER_ITERATIONS else "a smoke run's" if self.smoke else (
            f"{self.iterations / PAPER_ITERATIONS:.1%} of the paper's 300,000")
        return (f"plan: {len(self.argv) // len(VARIANTS)} tasks × {' and '.join(VARIANTS)} × "
                f"{self.models // len(self.argv)} models ({', '.join(METHODS)}; "
                f"{self.seeds} seed(s)), {self.iterations:,} iterations ({paper}); estimate {self.total_s:,.0f} s "
                f"of the {limit_s:,.0f} s limit: training {self.train_s:,.0f} s at {self.rate:,.0f} model-updates/s, "
                f"evaluation {self.eval_s:,.0f} s, demonstration frames {self.frames_s:,.0f} s, start and "
                f"compilation {self.fixed_s:,.0f} s")


def sweep_args(env: str, variant: str, iterations: int | None, dtype: str, smoke: bool) -> list[str]:
    """`experiments.sweep`'s arguments for `env`'s `variant` (`VARIANTS`) of the grid (`--out` apart)."""
    out = ["--env", env, "--obs", "image", "--preset", "default", "--methods", ",".join(METHODS),
           "--set", f"budget.seeds={SEEDS}", "--set", "protocol.frames=states", "--set", "recipe.perception=task",
           "--set", f"recipe.perception_training={variant}", "--set", "ours-step.grid=0.1:5",
           "--set", f"ours-softmax.taus={TAU[env]}", "--set", f"fca.alphas={ALPHA[env]}",
           "--set", f"recipe.dtype={dtype}", "--set", f"budget.width={len(METHODS) * SEEDS}",
           "--set", "budget.eval_at="]
    if smoke:
        out.append("--smoke")
    if iterations is not None:
        out += ["--set", f"budget.iterations={iterations}"]
    return out


def plan(tasks: tuple[str, ...], limit_s: float, iterations: int | None, rate: float | None, dtype: str,
         smoke: bool) -> Plan:
    """The plan for `tasks` within `limit_s` (module docstring); `ValueError` (one line) if it cannot fit."""
    import jax

    from experiments.bench_images import update_flops
    from experiments.sweep import cost

    backend = "gpu" if jax.default_backend() == "gpu" else "cpu"
    # smoke: the same code paths, seconds of work
    specs = {(env, v): _spec(env, v, dtype, smoke) for env in tasks for v in VARIANTS}
    first = next(iter(specs.values()))
    side, batch, chunk = first.protocol.image_size[0], first.recipe.batch_size, first.budget.chunk
    costs = {key: cost(key[0], s.settings, METHODS) for key, s in specs.items()}
    models = sum(c.configurations * c.seeds for c in costs.values())
    if rate is None:
        tuned = specs[(tasks[0], "finetune")].recipe
        flops = update_flops("perception", side, dtype, batch, perception_sha256=tuned.perception_sha256)
        rate = min(PRIOR_FLOPS[backend] / (flops or 34.0e9), PRIOR_SMALL_RATE[backend])
    steps = PRIOR_STEPS[backend]
    length = {key: s.setup.applied.settings.get("episode_length") or 1000 for key, s in specs.items()}
    eval_steps = sum(c.episodes * length[key] for key, c in costs.items())
    frames = sum(s.episodes * length[key] for key, s in specs.items())   # each sweep renders its own
    eval_s, frames_s, fixed_s = eval_steps / steps, frames / steps, PRIOR_FIXED_S[backend]
    room = limit_s - MARGIN_S - fixed_s - eval_s - frames_s
    if smoke:
        iterations = next(iter(costs.values())).iterations
    elif iterations is None:
        iterations = min(PAPER_ITERATIONS, int(max(room, 0) * rate / models) // chunk * chunk)
        if iterations < chunk:
            raise ValueError(f"the plan does not fit in {limit_s:,.0f} s: start, compilation, evaluation and "
                             f"frames alone take ~{limit_s - room - MARGIN_S:,.0f} s by the estimate, leaving "
                             f"less than one {chunk:,}-iteration chunk of training; give a longer --limit-s")
    train_s = models * iterations / rate
    out = Plan(iterations, chunk, models, first.budget.seeds, rate, train_s, eval_s, frames_s, fixed_s,
               {f"{env}-{v}": sweep_args(env, v, None if smoke else iterations, dtype, smoke) for env, v in specs},
               smoke)
    if out.total_s + MARGIN_S > limit_s and not smoke:
        raise ValueError(f"the plan's estimate, {out.total_s + MARGIN_S:,.0f} s ({iterations:,} iterations), "
                         f"exceeds the limit of {limit_s:,.0f} s; give fewer --iterations or a longer --limit-s")
    return out


def _spec(env: str, variant: str, dtype: str, smoke: bool = False):
    """The `SweepSpec` of `env`'s `variant` sweep in the plan (its `--set`s; the iterations aside)."""
    from ape_jax.pipeline.presets import resolve
    from ape_jax.pipeline.spec import SweepSpec

    argv = sweep_args(env, variant, None, dtype, False)
    sets = [value for flag, value in zip(argv, argv[1:]) if flag == "--set"]
    return SweepSpec(env, "image", resolve(env, "image", preset="default", sets=sets, smoke=smoke), METHODS)


def missing_demonstrations(tasks: tuple[str, ...], dtype: str) -> list[str]:
    """The collect commands of the tasks whose state demonstrations (`setup.state_source`) are not cached."""
    from ape_jax.pipeline import data as data_lib
    from ape_jax.pipeline.setup import state_source

    out = []
    for env in tasks:
        key = state_source(_spec(env, VARIANTS[0], dtype).setup.data_key)
        if not data_lib.cache_path(data_lib.cache_dir(), key).exists():
            out.append(f"APE_JAX_CACHE={data_lib.cache_dir()} python -m experiments.collect --env {env} --obs pos "
                       f"--protocol brax --episodes {key['episodes']}")
    return out


def run(p: Plan, out: pathlib.Path, work: pathlib.Path, limit_s: float) -> dict:
    """Runs the plan's sweeps side by side; `{name: {"rc", "wall_s", "finished"}}` (name: `<env>-<variant>`)."""
    env_vars = dict(os.environ, PYTHONUNBUFFERED="1")
    env_vars.setdefault("XLA_PYTHON_CLIENT_MEM_FRACTION", f"{0.9 / len(p.argv):.2f}")  # the sweeps share the card
    procs = {}
    t0 = time.monotonic()
    for name, argv in p.argv.items():
        (out / name).mkdir(parents=True, exist_ok=True)
        log = open(out / name / "log.txt", "w")  # noqa: SIM115 - closed below, after the process ends
        cmd = [sys.executable, "-m", "experiments.sweep", *argv, "--quiet", "--out", str(work / name)]
        procs[name] = (subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env_vars), log, cmd)
    status = {}
    for name, (proc, log, cmd) in procs.items():
        try:
            rc = proc.wait(timeout=max(limit_s - (time.monotonic() - t0), 1.0))
        except subprocess.TimeoutExpired:
            proc.terminate()
            rc = proc.wait()
        log.close()
        finished = (work / name / "results.json").exists()
        for file in ("results.json", "results.csv"):
            if (work / name / file).exists():
                (out / name / file).write_bytes((work / name / file).read_bytes())
        status[name] = {"rc": rc, "wall_s": round(time.monotonic() - t0, 1), "finished": finished,
                       "command": " ".join(["python", "-m", "experiments.sweep", *cmd[3:]])}
        print(f"== {name}: {'finished' if finished else f'stopped (exit {rc}) before it finished'} after "
              f"{status[name]['wall_s']:,.0f} s; its log: {out / name / 'log.txt'}", flush=True)
    return status


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.device.images", description=__doc__.splitlines()[0])
    p.add_argument("--limit-s", type=float, default=None,
                   help="seconds the whole plan may take (default: 480; --smoke: 1,500, for a busy 2-core CPU)")
    p.add_argument("--iterations", type=int, default=None,
                   help="training iterations per model (default: the paper's 300,000, or the most that fit)")
    p.add_argument("--rate", type=float, default=None,
                   help="the device's model-updates/s for the drq grid, all sweeps together (default: the prior)")
    p.add_argument("--tasks", type=lambda s: tuple(s.split(",")), default=TASKS,
                   help=f"comma list of {', '.join(TASKS)} (default: all three)")
    p.add_argument("--dtype", default=None, help="float32 or bfloat16 (default: bfloat16 on a GPU, else float32)")
    p.add_argument("--smoke", action="store_true", help="a smoke run's sizes (any backend): checks the plan runs")
    p.add_argument("--dry-run", action="store_true", help="print the plan and its estimate; run nothing")
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("runs/device-images"),
                   help="where the results, logs and plan.json go (default: runs/device-images)")
    p.add_argument("--work", type=pathlib.Path, default=pathlib.Path("/tmp/ape_device/images"),
                   help="the sweeps' run folders, checkpoints included (default: /tmp/ape_device/images)")
    args = p.parse_args(argv)
    if args.limit_s is None:
        args.limit_s = 1500.0 if args.smoke else 480.0
    import jax

    from ape_jax import models
    from ape_jax.pipeline import data as data_lib

    if bad := [t for t in args.tasks if t not in TASKS]:
        fail(p, f"--tasks: unknown {bad}; valid: {', '.join(TASKS)}")
    if args.limit_s <= 0 or (args.iterations is not None and args.iterations < 1) or (
            args.rate is not None and not (args.rate > 0 and math.isfinite(args.rate))):
        fail(p, "--limit-s, --iterations and --rate must be numbers > 0")
    dtype = args.dtype or ("bfloat16" if jax.default_backend() == "gpu" else "float32")
    if dtype not in models.DTYPES:
        fail(p, f"--dtype {dtype!r} is not one of {', '.join(models.DTYPES)}")
    if dtype == "bfloat16" and (problem := models.bf16_problem()):
        fail(p, f"--dtype bfloat16: {problem}; use --dtype float32")
    try:
        the_plan = plan(args.tasks, args.limit_s, args.iterations, args.rate, dtype, args.smoke)
    except ValueError as e:
        fail(p, str(e))
    print(the_plan.describe(args.limit_s), flush=True)
    missing = [] if args.smoke else missing_demonstrations(args.tasks, dtype)
    if args.dry_run:
        for name, a in the_plan.argv.items():
            print(f"  {name}: python -m experiments.sweep {' '.join(a)} --out {args.work / name}")
        print("demonstrations: " + ("; ".join(["missing: collect them first, on the CPU", *missing]) if missing else
                                    f"every task's state dataset is cached in {data_lib.cache_dir()}"))
        return 0
    if missing:
        fail(p, f"no state demonstrations cached for {len(missing)} task(s): collect them first, on the CPU: "
                + "; ".join(missing))
    for where in (args.out, args.work):
        if why := unwritable(where):
            fail(p, f"cannot write to {where}: {why}")
    args.out.mkdir(parents=True, exist_ok=True)
    record = {"plan": {**dataclasses.asdict(the_plan), "total_s": the_plan.total_s}, "limit_s": args.limit_s,
              "dtype": dtype, "backend": jax.default_backend(), "smoke": args.smoke}
    (args.out / "plan.json").write_text(json.dumps(record, indent=1) + "\n")
    t0 = time.monotonic()
    record["sweeps"] = run(the_plan, args.out, args.work, args.limit_s - MARGIN_S)
    record["wall_s"] = round(time.monotonic() - t0, 1)
    (args.out / "plan.json").write_text(json.dumps(record, indent=1) + "\n")
    done = sum(s["finished"] for s in record["sweeps"].values())
    print(f"== images: {done} of {len(record['sweeps'])} sweeps finished in {record['wall_s']:,.0f} s (estimate "
          f"{the_plan.total_s:,.0f} s); report them with: python -m experiments.report {args.out}/*/results.json")
    return 0 if done == len(record["sweeps"]) else 1


if __name__ == "__main__":
    sys.exit(main())
