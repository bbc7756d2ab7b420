"""Command-line helpers shared by the entry points.

Every entry point refuses bad input the same way: one line on stderr,
`PROG: error: WHAT`, and exit status 2 (argparse's convention), never a
traceback. `Parser` makes argparse's own refusals (unknown flag, invalid
choice, not a number) one line too; `fail` is for the checks the entry points
make themselves; `unwritable` and `unwritable_file` tell, before anything
expensive runs, why an output could not be written.
"""

from __future__ import annotations

import argparse
import errno
import os
import pathlib
import sys
import tempfile
from typing import NoReturn


_PROG: list[str] = []  # the program the last `Parser` named: `fail(None, ...)`'s prefix


class Parser(argparse.ArgumentParser):
    """An `ArgumentParser` whose errors are one line (no usage block), exit status 2. Started as a console script
    (`ape-sweep`, …: pyproject.toml's `[project.scripts]`), it names itself by that command. The last one made
    names the program for `fail(None, ...)`, so refusals made after parsing carry the same prefix."""

    def __init__(self, *args, **kwargs):
        command = os.path.basename(sys.argv[0]) if sys.argv else ""
        if command.startswith("ape-") and kwargs.get("prog", "").startswith("python -m experiments."):
            kwargs["prog"] = command
        super().__init__(*args, **kwargs)
        _PROG[:] = [self.prog]

    def error(self, message: str) -> NoReturn:
        fail(self, message)


def fail(parser: argparse.ArgumentParser | None, message: str) -> NoReturn:
    """Reports bad input on one line of stderr, `PROG: error: message`, and exits with status 2, without a
    traceback. `parser` None: PROG is the program the last `Parser` named (none made: no prefix)."""
    prog = f"{parser.prog}: " if parser is not None else f"{_PROG[0]}: " if _PROG else ""
    print(f"{prog}error: {' '.join(str(message).split())}", file=sys.stderr)
    raise SystemExit(2)


def unwritable(directory: str | os.PathLike) -> str | None:
    """Why files could not be created in `directory` (made if missing), or None if they can.

    Checks the nearest existing ancestor: it must be a directory in which a
    file can be created (probed with an anonymous temporary file, so read-only
    file systems are caught even when running as root). Nothing is left behind.
    """
    path = pathlib.Path(directory).absolute()
    existing = path
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        return f"{existing} is not a directory"
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as e:
        known = e.errno in (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT)
        return f"{existing} is not writable" + (f" ({e.strerror})" if known else "")
    return None


def unwritable_file(path: str | os.PathLike) -> str | None:
    """Why file `path` could not be written (replaced if it exists), or None if it can."""
    path = pathlib.Path(path)
    if path.is_dir():
        return f"{path} is a directory"
    return unwritable(path.parent)


def data_directory(parser: argparse.ArgumentParser, path: pathlib.Path | None) -> pathlib.Path:
    """`--data-dir`: the demonstration cache given (default `ape_jax.pipeline.data.cache_dir()`); a file is refused."""
    from ape_jax.pipeline import data

    path = path or data.cache_dir()
    if path.exists() and not path.is_dir():
        fail(parser, f"--data-dir {path} is a file; it must be a directory")
    return path


def add_compile_cache_flag(parser: argparse.ArgumentParser) -> None:
    """`--no-compile-cache` (see `use_compile_cache`)."""
    parser.add_argument("--no-compile-cache", action="store_true",
                        help="compile every program afresh (default: reuse JAX's persistent compilation cache in "
                             "the project's cache directory, xla/)")


def use_compile_cache(args: argparse.Namespace) -> pathlib.Path | None:
    """Turns on JAX's persistent compilation cache in `<cache dir>/xla` (`ape_jax.pipeline.data.cache_dir`), so a
    second run of the same programs loads them instead of compiling; returns its folder, or None where
    `--no-compile-cache` was given or the environment already names a cache (`JAX_COMPILATION_CACHE_DIR`, e.g.
    the tests' shared one): that choice is left alone."""
    if getattr(args, "no_compile_cache", False) or os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return None
    import jax

    from ape_jax.pipeline import data

    path = data.cache_dir() / "xla"
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)  # the many sub-second programs: not worth it
    return path
