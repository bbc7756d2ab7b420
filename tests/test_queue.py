"""The background queues' shell helpers (`results/queue/_lib.sh`), with `piece` stubbed: `pool` runs every piece
once, two at a time on cores 0 and 1 (the next to whichever frees first; either may start first), or one after
another on every core with PARALLEL=1, and reports a failed piece after trying the rest."""

import pathlib
import subprocess

import pytest

LIB = pathlib.Path(__file__).resolve().parents[1] / "results" / "queue" / "_lib.sh"

# `piece NAME CORES ARGS...` stubbed: logs "NAME CORES ARGS" and sleeps the seconds its name ends in; "bad*" fails
STUB = r'''
piece() {
  echo "$1 $2 ${*:3}" >> "$RUNS/log"
  sleep "${1##*-}"
  [[ $1 != bad* ]]
}
'''


def _pool(tmp_path, specs, parallel="2"):
    script = f'source "{LIB}"\n{STUB}\npool "$@"\necho "rc=$?" >> "$RUNS/log"\n'
    done = subprocess.run(["bash", "-c", script, "pool", *specs], env={"RUNS": str(tmp_path), "PARALLEL": parallel,
                          "PATH": "/usr/bin:/bin"}, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    lines = (tmp_path / "log").read_text().splitlines()
    return lines[:-1], lines[-1]


def test_pool_runs_every_piece_once_two_at_a_time_the_next_on_the_core_that_frees_first(tmp_path):
    ran, rc = _pool(tmp_path, ["long-2 --env hopper --seeds 5", "short-0.1 --env walker2d", "a-0.1", "b-0.1"])
    assert rc == "rc=0"
    by_name = {line.split()[0]: line.split()[1:] for line in ran}
    assert sorted(by_name) == ["a-0.1", "b-0.1", "long-2", "short-0.1"] and len(ran) == 4
    long_core = by_name["long-2"][0]
    assert long_core in ("0", "1") and by_name["long-2"][1:] == ["--env", "hopper", "--seeds", "5"]
    other = {"0": "1", "1": "0"}[long_core]   # the other core takes the rest while the long piece runs
    assert [by_name[n][0] for n in ("short-0.1", "a-0.1", "b-0.1")] == [other] * 3


def test_pool_reports_a_failed_piece_after_trying_the_others(tmp_path):
    ran, rc = _pool(tmp_path, ["bad-0.1", "ok-0.1", "fine-0.2"])
    assert rc == "rc=1" and sorted(line.split()[0] for line in ran) == ["bad-0.1", "fine-0.2", "ok-0.1"]


@pytest.mark.parametrize("failing", [False, True])
def test_with_parallel_1_pool_runs_the_pieces_one_after_another_on_every_core(tmp_path, failing):
    ran, rc = _pool(tmp_path, ["bad-0" if failing else "x-0", "y-0 --seeds 2"], parallel="1")
    assert [line.split()[:2] for line in ran] == [["bad-0" if failing else "x-0", "all"], ["y-0", "all"]]
    assert ran[1].endswith("--seeds 2") and rc == ("rc=1" if failing else "rc=0")
