"""Host loops a Ctrl-C stops at once: a jitted program compiled in a background thread while the main thread
waits (`compiled`), whether one is still compiling after an interrupt (`compiling`), and what an interrupted
collection says (`CollectionInterrupted`). `ape_jax.pipeline.collect` runs its chunks through them; an entry point
asks `compiling` before it exits (`experiments._cli`)."""

from __future__ import annotations

import threading
from collections.abc import Callable

import jax


class CollectionInterrupted(KeyboardInterrupt):
    """Ctrl-C while `collect` ran: nothing was returned (so nothing cached); `done` of `total` episodes had been
    collected."""

    def __init__(self, done: int, total: int):
        super().__init__(f"stopped the collection of {total:,} expert episodes ({done:,} collected, nothing cached)")
        self.done, self.total = done, total


_COMPILES: set[threading.Event] = set()   # one per compile a Ctrl-C left running, set when it ends (`compiling`)


def compiling() -> bool:
    """Whether a collection program is still compiling in the background: a Ctrl-C stopped the wait for it."""
    return any(not finished.is_set() for finished in _COMPILES)


def compiled(fn: Callable, *args) -> Callable:
    """`jax.jit(fn).lower(*args).compile()`, run in a daemon thread while this one waits for it.

    XLA's compile of a collection program takes seconds (ToyTown's, ~7 s; several times that on a loaded CPU) and
    holds the thread that runs it: Python runs a Ctrl-C's handler only once that thread is back in Python. Waiting
    here, the KeyboardInterrupt is raised at once and the compile is abandoned (`compiling` says so: an entry
    point then ends the process with `os._exit`, since tearing the interpreter down under XLA crashes it). The
    persistent compilation cache applies as it does to any jitted call.
    """
    box: dict = {}
    finished = threading.Event()   # not `Thread.join`: an interrupted join marks a running thread stopped

    def work():
        try:
            box["program"] = jax.jit(fn).lower(*args).compile()
        except BaseException as e:   # handed to the waiting thread, which raises it
            box["error"] = e
        finally:
            finished.set()

    _COMPILES.add(finished)
    threading.Thread(target=work, name="ape_jax-compile", daemon=True).start()
    while not finished.wait(0.05):   # a Ctrl-C raises here
        pass
    _COMPILES.discard(finished)
    if "error" in box:
        raise box["error"]
    return box["program"]
