"""Entry points: quiet imports, clear refusals with exit code 2."""

import pathlib
import subprocess
import sys

import pytest

from experiments import _timing, collect


@pytest.mark.integration
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


@pytest.mark.parametrize("command, args", [
    ("ape-sweep", ["--env", "nope"]),
    ("ape-report", ["/nonexistent/results.json"]),
    ("ape-evaluate", ["/nonexistent/run"]),
    ("ape-collect", ["--env", "nope"]),
    ("ape-compare", ["/nonexistent/run"]),
])
def test_the_console_scripts_run_the_entry_points_with_their_one_line_errors(command, args):
    """pyproject.toml's `[project.scripts]`, installed beside the interpreter by `pip install -e .`."""
    script = pathlib.Path(sys.executable).parent / command
    assert script.exists(), f"{command} is not installed beside {sys.executable}: pip install -e ."
    proc = subprocess.run([str(script), *args], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"{command}: error: "), proc.stderr


def test_the_entry_points_use_the_persistent_compilation_cache_unless_told_not_to(tmp_path, monkeypatch):
    """`use_compile_cache`: the project's cache folder's xla/, unless --no-compile-cache or the environment names
    one (the tests' shared cache is left alone)."""
    import argparse

    import jax

    from experiments import _cli

    before = jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "theirs"))
    assert _cli.use_compile_cache(argparse.Namespace(no_compile_cache=False)) is None
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR")
    monkeypatch.setenv("APE_JAX_CACHE", str(tmp_path / "cache"))
    assert _cli.use_compile_cache(argparse.Namespace(no_compile_cache=True)) is None
    assert jax.config.jax_compilation_cache_dir == before[0]
    try:
        assert _cli.use_compile_cache(argparse.Namespace(no_compile_cache=False)) == tmp_path / "cache" / "xla"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "cache" / "xla")
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])
