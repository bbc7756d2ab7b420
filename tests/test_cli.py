"""Entry points: quiet imports, clear refusals with exit code 2."""

import subprocess
import sys

import pytest

from experiments import _timing, collect


def test_importing_and_making_envs_prints_nothing():
    code = "import envs; envs.make('halfcheetah', obs='pos'); envs.make('hopper')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "" and out.stderr == "", (out.stdout, out.stderr)


def test_benchmark_section_is_replaced_in_place(tmp_path):
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\nintro\n")
    _timing.write_section(str(path), "## Environment throughput\n\nold\n")
    _timing.write_section(str(path), "## Environment throughput\n\nnew\n")
    text = path.read_text()
    assert text.count("## Environment throughput") == 1 and "new" in text and "old" not in text
    assert text.startswith("# Benchmarks\n\nintro\n")


@pytest.mark.parametrize(
    "argv,message",
    [
        (["--env", "hoper"], "unknown env 'hoper'"),
        (["--env", "toycar", "--obs", "pos"], "not supported by toycar"),
        (["--noise-frac", "1.5"], "--noise-frac must be in [0, 1]"),
        (["--episodes", "0"], ">= 1"),
        (["--obs", "pos", "--image-size", "32"], "applies to --obs image only"),
        (["--obs", "image", "--image-size", "big"], "--image-size"),
        (["--preview", "out.mp4"], "must name a .gif"),
    ],
)
def test_collect_refuses_bad_input_with_exit_code_2(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        collect.main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_collect_writes_a_dataset_then_reuses_it(tmp_path, capsys):
    argv = ["--env", "toycar", "--obs", "full", "--episodes", "3", "--data-dir", str(tmp_path)]
    assert collect.main(argv) == 0
    assert "collected" in capsys.readouterr().out
    files = sorted(p.suffix for p in tmp_path.iterdir())
    assert files == [".json", ".npz"]
    assert collect.main([*argv, "--preview", str(tmp_path / "first.gif")]) == 0
    assert "loaded cached" in capsys.readouterr().out
    from PIL import Image

    with Image.open(tmp_path / "first.gif") as gif:  # the first episode, re-rendered from its sim states
        assert gif.n_frames > 50 and gif.size == (128, 128)
