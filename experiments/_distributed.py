"""Several processes, one sweep: `--coordinator`, `--num-processes`, `--process-id`.

    procs = start(PROG, argv)      # before anything imports the environments (that starts JAX)
    ...
    code = procs.agree(code, fingerprint)   # every process's verdict before training

`start` reads the three flags before JAX starts (its distributed runtime must
come up before the first computation, and importing the environments already
computes), refuses bad ones with one line and exit status 2, and calls
`jax.distributed.initialize`. With none of the flags but `JAX_COORDINATOR_ADDRESS`
set, JAX itself takes the process count and index from the cluster it detects
(SLURM, Open MPI, Kubernetes). Without either, the sweep is one process, as before.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import zlib

from experiments._cli import Parser, fail

# The other processes train only, then wait for process 0 to evaluate and write (`Processes.wait_for_writer`) before
# JAX's shutdown barrier: the barrier's call gives up after 5 minutes whatever the service allows, which aborted them
# in the middle of a long evaluation. The wait and the service's barrier are both bounded by a day.
SHUTDOWN_TIMEOUT_S = 24 * 3600
WRITTEN_KEY = "ape_jax/sweep/written"   # the coordination service's key process 0 sets when it ends (`release`)
# A process whose heartbeats miss this long counts as dead and aborts them all. JAX's 100 s killed a 300k sweep in
# its evaluation (exit 134, "Task 1 heartbeat timeout": process 1, aborted at the shutdown barrier, had stopped
# beating). Half an hour lets a starved process (nice 19 beside a busy machine) live and still ends a run whose peer
# truly died.
HEARTBEAT_TIMEOUT_S = 30 * 60
GO = 255  # a verdict: nothing to stop for (exit codes are below it)


def add_flags(p: argparse.ArgumentParser) -> None:
    """The three flags, on the entry point's own parser (for --help; `start` has read them already)."""
    g = p.add_argument_group("several processes (jax.distributed; all three, or none)")
    g.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="address of process 0, which every process connects to (default: JAX_COORDINATOR_ADDRESS, "
                        "with the count and index from the cluster JAX detects, or one process)")
    g.add_argument("--num-processes", type=int, default=None, metavar="N", help="how many processes run the sweep")
    g.add_argument("--process-id", type=int, default=None, metavar="I",
                   help="this process's index in [0, N); process 0 alone writes --out")


@dataclasses.dataclass(frozen=True)
class Processes:
    """The processes that run one sweep: how many, and which this is."""

    count: int = 1
    index: int = 0

    @property
    def writes(self) -> bool:
        """Whether this process writes the sweep's files (process 0 only)."""
        return self.index == 0

    def agree(self, code: int | None, fingerprint: dict | None) -> int | None:
        """Every process's verdict before training: None to train, or the exit status to stop with.

        Args:
          code: this process's verdict: None to go on, 2 for a refusal it has
            printed, 0 for a finished sweep (process 0, which has reported it).
          fingerprint: the sweep's settings (`SweepSpec.fingerprint`), None if refused.

        A refusal on any process, or a finished sweep, stops every process;
        processes started with other settings than process 0 are refused. One
        process: `code` as it is. Every process must call it.
        """
        if self.count == 1:
            return code
        import numpy as np
        from jax.experimental import multihost_utils

        settings = zlib.crc32(json.dumps(fingerprint, sort_keys=True, default=str).encode())
        mine = np.array([GO if code is None else code, settings], np.uint32)
        every = np.asarray(multihost_utils.process_allgather(mine)).reshape(self.count, 2)
        verdicts, settings = every[:, 0], every[:, 1]
        if code is not None:
            return code
        refused = [i for i, v in enumerate(verdicts) if v not in (GO, 0)]
        if refused:
            return fail(None, f"process {self.index}: process(es) {', '.join(map(str, refused))} refused the sweep "
                              "(their output says why)")
        if verdicts[0] == 0:
            return 0  # process 0 found it finished and reported it
        differ = [i for i, s in enumerate(settings) if s != settings[0]]
        if differ:
            fail(None, f"process {self.index}: process(es) {', '.join(map(str, differ))} were started with other "
                       "settings than process 0; start every process with the same command (but --process-id)")
        return None

    def release(self) -> None:
        """Process 0, ending (written, refused or failed): lets the others end (`wait_for_writer`)."""
        if self.count > 1 and self.writes:
            _client().key_value_set(WRITTEN_KEY, "1")

    def wait_for_writer(self) -> int:
        """Another process, its share trained: waits, its heartbeats going on, until process 0 ends (`release`),
        so every process reaches JAX's shutdown barrier together. 0, or 1 with a line where the wait fails (a day
        passed). Where process 0 dies without releasing it, its coordination service goes with it and JAX's client
        aborts this process (process 0's output says why)."""
        if self.count == 1 or self.writes:
            return 0
        try:
            _client().blocking_key_value_get(WRITTEN_KEY, SHUTDOWN_TIMEOUT_S * 1000)
        except Exception as e:   # the service's errors come as XlaRuntimeError
            print(f"process {self.index}: waiting for process 0 failed ({str(e).splitlines()[0][:200]}); its output "
                  "says why", file=sys.stderr)
            return 1
        return 0


def _client():
    """JAX's coordination-service client of this process (set up by `jax.distributed.initialize`)."""
    from jax._src import distributed

    return distributed.global_state.client


def start(prog: str, argv: list[str] | None) -> Processes:
    """Reads `--coordinator/--num-processes/--process-id` from `argv` and starts JAX's distributed runtime.

    Refuses (one line, exit status 2) a count below 1, an index outside
    `[0, count)`, a coordinator not of the form HOST:PORT, or some of the flags
    without the others, before JAX starts. Returns `Processes()` (one) when
    there is nothing to start.
    """
    p = Parser(prog=prog, add_help=False)
    add_flags(p)
    args, _ = p.parse_known_args(argv)
    given = [f for f, v in (("--coordinator", args.coordinator), ("--num-processes", args.num_processes),
                            ("--process-id", args.process_id)) if v is not None]
    if given and len(given) < 3:
        missing = sorted({"--coordinator", "--num-processes", "--process-id"} - set(given))
        fail(p, f"{' and '.join(given)} without {' and '.join(missing)}: give all three, or none")
    if not given:
        if not os.environ.get("JAX_COORDINATOR_ADDRESS"):
            return Processes()
        return _initialize(p)  # JAX reads the address, and takes the count and index from its cluster
    host, sep, port = args.coordinator.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        fail(p, f"--coordinator {args.coordinator!r} is not HOST:PORT (e.g. 10.0.0.1:1234)")
    if args.num_processes < 1:
        fail(p, f"--num-processes must be >= 1, got {args.num_processes}")
    if not 0 <= args.process_id < args.num_processes:
        fail(p, f"--process-id must be in [0, {args.num_processes}), got {args.process_id}")
    if args.num_processes == 1:
        return Processes()
    return _initialize(p, coordinator_address=args.coordinator, num_processes=args.num_processes,
                       process_id=args.process_id)


def _initialize(p: argparse.ArgumentParser, **where) -> Processes:
    import jax

    try:
        jax.distributed.initialize(shutdown_timeout_seconds=SHUTDOWN_TIMEOUT_S,
                                   heartbeat_timeout_seconds=HEARTBEAT_TIMEOUT_S, **where)
    except (ValueError, TypeError, RuntimeError) as e:  # e.g. JAX_COORDINATOR_ADDRESS outside a cluster JAX knows
        hint = ("" if where else " (JAX_COORDINATOR_ADDRESS is set: outside SLURM, Open MPI or Kubernetes, give "
                "--coordinator, --num-processes and --process-id instead)")
        fail(p, f"jax.distributed.initialize: {str(e).splitlines()[0] if str(e) else type(e).__name__}{hint}")
    return Processes(jax.process_count(), jax.process_index())
