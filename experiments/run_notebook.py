"""Execute a notebook top to bottom in a fresh kernel: `python -m experiments.run_notebook docs/tutorial.ipynb`.

How CI keeps the tutorial from rotting (`.ci/run`). The notebook runs with
nbclient in a new kernel named `--kernel` (default `python3`: ipykernel's own,
which jupyter_client starts with this interpreter), in the notebook's folder as
Jupyter would; before the first cell the kernel is asked which Python it is,
and one other than this one (a `python3` kernel spec of another environment
found first) is a failure, not a silent pass. Each cell may run `--timeout`
seconds. It prints every code cell's time and the total wall time; `--out FILE`
keeps the executed copy, outputs and figures included (the notebook itself is
never written).

Exit status: 0 when every cell ran; 1 when a cell raised, timed out or killed
the kernel (the cell named by its number and first line, the error below it);
2, with one line on stderr, for input that cannot be used (a missing file, one
that is not an nbformat 4 notebook, an unknown kernel, an `--out` that cannot
be written) and where the test extra (nbclient, nbformat, ipykernel) is not
installed, naming the command that installs it.
"""

from __future__ import annotations

import pathlib
import sys
import time

from experiments._cli import Parser, fail, unreadable, unwritable_file

# the kernel's answer before the first cell: the interpreter and the environment it belongs to
PROBE = "import sys; print(sys.executable); print(sys.prefix)"


class WrongKernel(Exception):
    """The kernel runs another Python environment than this one (one line)."""


def first_line(cell) -> str:
    """A cell's first non-blank line, shortened: how a failure names it."""
    line = next((s.strip() for s in cell.source.splitlines() if s.strip()), "(empty)")
    return line if len(line) <= 80 else line[:77] + "..."


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.run_notebook", description=__doc__.splitlines()[0])
    p.add_argument("notebook", type=pathlib.Path, help="the .ipynb file to execute")
    p.add_argument("--timeout", type=int, default=600, help="seconds one cell may run (default: 600)")
    p.add_argument("--kernel", default="python3", help="the kernel to start (default: python3, this Python's)")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write the executed notebook, with its outputs, here (default: nowhere)")
    args = p.parse_args(argv)
    if args.timeout < 1:
        fail(p, f"--timeout must be >= 1 second, got {args.timeout}")
    if not args.notebook.exists():
        fail(p, f"{args.notebook}: no such notebook file")
    if why := unreadable(args.notebook, "a notebook file"):
        fail(p, why)
    if args.out is not None and (why := unwritable_file(args.out)):
        fail(p, f"--out {args.out}: cannot write there: {why}")

    try:  # the test extra's (pyproject.toml), not the project's own dependencies
        import nbformat
        from jupyter_client.kernelspec import NoSuchKernel
        from nbclient import NotebookClient
        from nbclient.exceptions import CellControlSignal, CellExecutionError, DeadKernelError
        if args.kernel == "python3":
            import ipykernel  # noqa: F401 - provides the python3 kernel
    except ImportError as e:
        fail(p, f"{e.name or 'a module it needs'} is not installed: running notebooks needs the test extra, "
                f"pip install -e \".[test]\"")

    try:
        nb = nbformat.read(args.notebook, as_version=4)
        nbformat.validate(nb)
    except Exception as e:  # noqa: BLE001 - JSON, schema and I/O errors alike: the file is not a usable notebook
        fail(p, f"{args.notebook}: not a valid nbformat 4 notebook ({type(e).__name__}: "
                f"{str(e).splitlines()[0] if str(e) else ''})")
    cells = list(nb.cells)
    nb.cells.insert(0, nbformat.v4.new_code_cell(PROBE, id="run-notebook-probe"))
    seconds: dict[int, float] = {}
    current = {"index": None, "start": 0.0}
    kernel = {}

    def started(cell, cell_index, **_):
        current.update(index=cell_index - 1, start=time.perf_counter())

    def finished(cell, cell_index, **_):  # the reply came: the cell ran, or raised
        seconds[cell_index - 1] = time.perf_counter() - current["start"]
        if cell_index == 0:  # the probe: stop before the notebook's first cell if the kernel is not this Python's
            answer = "".join(o.get("text", "") for o in cell.outputs if o.get("output_type") == "stream")
            executable, _, prefix = answer.strip().partition("\n")
            kernel.update(executable=executable, prefix=prefix.strip())
            if kernel["prefix"] != sys.prefix:
                raise WrongKernel(f"the kernel {args.kernel!r} runs {executable} (environment {kernel['prefix']}), "
                                  f"not this Python's environment {sys.prefix}: a kernel spec of that name elsewhere "
                                  "comes first (`jupyter kernelspec list`)")

    client = NotebookClient(nb, timeout=args.timeout, kernel_name=args.kernel,
                            resources={"metadata": {"path": str(args.notebook.resolve().parent)}},
                            on_cell_start=started, on_cell_executed=finished)
    t0 = time.perf_counter()
    failure = None
    try:
        client.execute()
    except NoSuchKernel:
        fail(p, f"no kernel named {args.kernel!r} (`jupyter kernelspec list`; ipykernel provides python3)")
    except WrongKernel as e:
        print(f"{args.notebook}: {e}", file=sys.stderr)
        return 1
    except (CellExecutionError, CellControlSignal, DeadKernelError, RuntimeError) as e:
        failure = e  # a cell raised, timed out (CellTimeoutError, a control signal) or the kernel died
    wall = time.perf_counter() - t0
    nb.cells.pop(0)
    if args.out is not None:
        nbformat.write(nb, args.out)
    where = args.notebook
    index = current["index"]
    if failure is not None:
        if index is None or index < 0:
            print(f"{where}: the kernel failed before the first cell: {failure}", file=sys.stderr)
        else:
            code_number = sum(c.cell_type == "code" for c in cells[:index + 1])
            print(f"{where}: cell {index + 1} of {len(cells)} (code cell {code_number}: {first_line(cells[index])}) "
                  f"failed after {time.perf_counter() - current['start']:.0f} s:\n{failure}", file=sys.stderr)
        print(f"{where}: FAILED after {wall:.0f} s", file=sys.stderr)
        return 1
    for i, cell in enumerate(cells):
        if i in seconds and cell.cell_type == "code":
            print(f"  cell {i + 1:>3}: {seconds[i]:6.1f} s  {first_line(cell)}")
    code = sum(c.cell_type == "code" for c in cells)
    print(f"{where}: {code} code cells ran in {wall:.0f} s ({wall / 60:.1f} min, kernel start included); "
          f"kernel {args.kernel} on {kernel['executable']}" + (f"; executed copy: {args.out}" if args.out else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
