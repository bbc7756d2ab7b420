"""Command-line helpers shared by the entry points.

Every entry point refuses bad input the same way: one line on stderr,
`PROG: error: WHAT`, and exit status 2 (argparse's convention), never a
traceback. `Parser` makes argparse's own refusals (unknown flag, invalid
choice, not a number) one line too; `fail` is for the checks the entry points
make themselves; `unreadable` and `not_a_folder` say what is wrong with an input path (missing, a folder where a
file is expected, a file where a folder is); `unwritable` and `unwritable_file` tell, before anything expensive
runs, why an output could not be written. `UPDATES_LIMIT` and `EPISODES_LIMIT` bound what a command may ask for
without `--yes`.

Ctrl-C stops a run with exit status 130 and one line. Python ignores an exception raised where it cannot be
propagated (a `gc.callbacks` function such as JAX's `_xla_gc_callback`, a finalizer), so a Ctrl-C landing there
would be lost: inside `interrupts()` it is recorded, never reported as "Exception ignored", and
`raise_if_interrupted` (called between chunks by `checked_bar`'s bars, and before results are written) raises it.
A Ctrl-C during a collection's compile (run in the background so it is not held for it) leaves the compile
running: `end_if_compiling` ends such a process at once.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import functools
import os
import pathlib
import signal
import sys
import tempfile
import threading
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


_OURS = tuple(str(pathlib.Path(__file__).resolve().parents[1] / d) + os.sep for d in ("ape_jax", "experiments", "envs"))


def refused(e: Exception) -> bool:
    """Whether an error an entry point catches as a refusal is one, to be reported on one line: the project's own
    error types always; a `ValueError` where this project's code raised it (`ape_jax`, `experiments`, `envs`), not
    a library (a JAX shape error: a bug, whose traceback must show). Reads where the innermost frame of its
    traceback lies; a fault whose library frames JAX's traceback filtering hid still reads as a refusal (the
    heuristic errs towards the one line)."""
    tb = e.__traceback__
    if not isinstance(e, ValueError) or tb is None:
        return True
    while tb.tb_next is not None:
        tb = tb.tb_next
    return str(pathlib.Path(tb.tb_frame.f_code.co_filename).resolve()).startswith(_OURS)


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
    """`--data-dir`: the demonstration cache given (default `ape_jax.pipeline.data.cache_dir()`); a file is refused
    (one that must be written, a path under a file too, is checked where it is known to be written)."""
    from ape_jax.pipeline import data

    path = path or data.cache_dir()
    if path.exists() and not path.is_dir():
        fail(parser, f"--data-dir {path} is a file; it must be a directory")
    return path


def _nearest_existing(path: pathlib.Path) -> pathlib.Path:
    """`path`, or its nearest ancestor that exists."""
    path = pathlib.Path(path).absolute()
    while not path.exists() and path.parent != path:
        path = path.parent
    return path


def unreadable(path: str | os.PathLike, what: str) -> str | None:
    """Why `path` cannot be read as `what` (a file, e.g. "a results file"), or None if it can: it does not exist,
    it is a folder, it is not a regular file, or opening it fails."""
    path = pathlib.Path(path)
    if not path.exists():
        above = _nearest_existing(path)
        return f"{path} does not exist" + (f" ({above} is a file, not a folder)" if not above.is_dir() else "")
    if path.is_dir():
        return f"{path} is a folder, not {what}"
    if not path.is_file():
        return f"{path} is not a regular file, not {what}"
    try:
        with open(path, "rb"):
            pass
    except OSError as e:
        return f"{path} cannot be read ({e.strerror or e})"
    return None


def not_a_folder(path: str | os.PathLike, what: str) -> str | None:
    """Why `path` is not an existing folder (`what`: e.g. "a sweep's --out folder"), or None if it is one."""
    path = pathlib.Path(path)
    if not path.exists():
        return f"{path} does not exist"
    if not path.is_dir():
        return f"{path} is a file, not {what}"
    return None


# A command past either is refused unless --yes: a typo (--seeds 1000000) would otherwise hold the machine for
# months. The paper preset with every method is ~1e8 updates; the README's and the default sweeps ~1e4 to 1e6.
UPDATES_LIMIT = 1_000_000_000   # model updates: one policy, one batch, one optimiser step
EPISODES_LIMIT = 1_000_000      # episodes: a sweep's evaluation episodes, or the episodes collect rolls out


# -- Ctrl-C -------------------------------------------------------------------------------------------------------

_INTERRUPTED = threading.Event()   # a SIGINT arrived inside `interrupts()`, whether or not its exception got through


def _on_sigint(signum, frame) -> None:
    _INTERRUPTED.set()
    raise KeyboardInterrupt


def _unraisable(hook):
    """`sys.unraisablehook` for `interrupts()`: a KeyboardInterrupt that Python had to ignore is recorded, not
    printed (`raise_if_interrupted` raises it); anything else goes to `hook`."""
    def report(info) -> None:
        if info.exc_type is not None and issubclass(info.exc_type, KeyboardInterrupt):
            _INTERRUPTED.set()
            return
        hook(info)
    return report


@contextlib.contextmanager
def interrupts():
    """Within the block Ctrl-C (SIGINT) raises KeyboardInterrupt as usual and is also recorded, so one that lands
    where Python ignores exceptions (a gc callback, a finalizer) is raised again by `raise_if_interrupted`. The
    previous handler and `sys.unraisablehook` are restored on leaving. Off the main thread: nothing is changed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _INTERRUPTED.clear()
    previous_handler, previous_hook = signal.getsignal(signal.SIGINT), sys.unraisablehook
    signal.signal(signal.SIGINT, _on_sigint)
    sys.unraisablehook = _unraisable(previous_hook)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.SIG_DFL if previous_handler is None else previous_handler)
        sys.unraisablehook = previous_hook
        _INTERRUPTED.clear()


def raise_if_interrupted() -> None:
    """Raises KeyboardInterrupt if a Ctrl-C arrived inside `interrupts()` (its own exception may have been
    ignored): called at the points where stopping is safe, between chunks and before results are written."""
    if _INTERRUPTED.is_set():
        raise KeyboardInterrupt


def end_if_compiling(code: int) -> None:
    """Ends the process now with exit status `code` where a Ctrl-C left a program compiling in the background (a
    collection's, `ape_jax.pipeline.collect.compiling`); otherwise returns. XLA's compile cannot be stopped and
    tearing the interpreter down under it crashes (exit 139), so the output is flushed and the process leaves
    with `os._exit`: call it last, once files and locks are dealt with."""
    collect = sys.modules.get("ape_jax.pipeline.collect")   # not imported: nothing of it can be compiling
    if collect is not None and collect.compiling():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def interruptible(left: str):
    """Makes an entry point's `main(argv)` stop on Ctrl-C with one line, `PROG: interrupted; LEFT`, and exit status
    130 (run inside `interrupts()`); `left` says what the interrupted command leaves, e.g. "nothing was written"."""
    def wrap(main):
        @functools.wraps(main)
        def run(argv=None) -> int:
            try:
                with interrupts():
                    return main(argv)
            except KeyboardInterrupt:
                print(f"\n{_PROG[0] + ': ' if _PROG else ''}interrupted; {left}", file=sys.stderr)
                end_if_compiling(130)
                return 130
        return run
    return wrap


class _CheckedBar:
    """A progress bar whose every update first stops on a recorded Ctrl-C (`raise_if_interrupted`)."""

    def __init__(self, bar):
        self._bar = bar

    def __enter__(self):
        self._bar.__enter__()
        return self

    def __exit__(self, *exc):
        return self._bar.__exit__(*exc)

    def update(self, n=1):
        raise_if_interrupted()
        return self._bar.update(n)

    def __getattr__(self, name):
        return getattr(self._bar, name)


def checked_bar(bar):
    """`bar` (a `Hooks.bar`: `bar(desc=..., total=..., unit=...)`) whose bars call `raise_if_interrupted` on every
    update: a Ctrl-C whose exception was ignored stops the run at the next chunk."""
    return lambda **kw: _CheckedBar(bar(**kw))


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
