"""Entry points: quiet imports, clear refusals with exit code 2."""

import subprocess
import sys

import pytest

import envs

from experiments import bench_envs, sweep


def test_importing_and_making_envs_prints_nothing():
    code = "import envs; envs.make('halfcheetah', obs='pos'); envs.make('hopper')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "" and out.stderr == "", (out.stdout, out.stderr)


@pytest.mark.parametrize(
    "argv,message",
    [
        (["--env", "hoper"], "unknown env"),
        (["--env", "swimmer", "--obs", "image"], "not supported by swimmer"),
        (["--preset", "huge"], "invalid choice"),
        (["--episodes", "0"], ">= 1"),
        (["--steps", "many"], "invalid int"),
    ],
)
def test_sweep_refuses_bad_input_with_exit_code_2(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        sweep.parse(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_sweep_accepts_the_default_command_line():
    args = sweep.parse([])
    assert args.preset == "quick" and args.names == ["hopper", "halfcheetah", "walker2d", "toycar"]
    assert sweep.parse(["--env", "all"]).names == list(envs.names())


def test_benchmark_section_is_replaced_in_place(tmp_path):
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\nintro\n")
    bench_envs.write_section(str(path), "## Environment throughput\n\nold\n")
    bench_envs.write_section(str(path), "## Environment throughput\n\nnew\n")
    text = path.read_text()
    assert text.count("## Environment throughput") == 1 and "new" in text and "old" not in text
    assert text.startswith("# Benchmarks\n\nintro\n")
