"""One check shared by the methods' tests: the sweep refuses a command line in one line, before any work."""

import pytest


def assert_sweep_refuses(tmp_path, capsys, argv: list[str], message: str) -> None:
    """`experiments.sweep` on `argv` (plus a fresh `--out` and `--data-dir`) exits 2 with one line holding
    `message`, no traceback, and writes nothing: no demonstrations collected, nothing compiled or saved."""
    from experiments import sweep

    out, data = tmp_path / "out", tmp_path / "data"
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        sweep.main([*argv, "--out", str(out), "--data-dir", str(data)])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert message in err, err
    assert not out.exists() and not data.exists()
