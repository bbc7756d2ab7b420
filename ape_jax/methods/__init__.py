"""The method registry: one record per method, and the plugin contract.

Every method the sweep can train is one `Method` record, registered once. The
sweep, the command line's defaults and shortcuts, `results.json` and the
report read their lists of methods from here, so adding a method is one
module:

- a **built-in** is a module of `ape_jax.methods` or `ape_jax.baselines` that
  calls `register` (or `weighting`) at import; the registry imports every such
  module the first time it is asked for a method (`BUILTIN_PACKAGES`);
- a **plugin** is any module on `PYTHONPATH`, imported by the sweep's
  `--plugins` before the methods are resolved:

      import jax.numpy as jnp
      from ape_jax import methods

      @methods.weighting("action-norm")   # kind="step": ranked at the preset's (THR, W) grid, like ours-step
      def action_norm(key, actions, t):    # actions [N, A] float32, t [N] int32 -> scores [N] float32
          return jnp.sum(actions ** 2, axis=-1)

A weighting method's scores become one row of the score table the weighted
learner reads (`ape_jax.weighting`; row 0 is the APE), so it trains in the
same vmapped grid program as BC-OH and the paper's grids. `kind` says how the
row becomes weights: `"step"` ranks it over the training set (top THR × W, at
each (THR, W) of the preset's step grid), `"softmax"` weights each minibatch by
`B · softmax(score / τ)` (each τ of the preset's softmax grid), `"given"` uses
the scores as the weights themselves (they must be >= 0).

Names are unique: registering a name twice is refused with the registered
names listed, and so is asking for an unknown one.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import pkgutil
import re
import sys
import zlib
from typing import Any
from collections.abc import Callable, Iterator, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

ROLES = ("reference", "ours", "baseline", "plugin")  # the order methods are listed in
WEIGHTING_KINDS = ("step", "softmax", "given")
OBSERVATIONS = (None, "full")  # `Method.observation`: the sweep's own, or the full state (`ape_jax.observations`)
BUILTIN_PACKAGES = ("ape_jax.methods", "ape_jax.baselines")
_NAME = re.compile(r"^[a-z0-9][a-z0-9_.-]*$")


class MethodError(ValueError):
    """An unknown or duplicate method, or a method record that does not make sense (one line)."""


class PluginError(ValueError):
    """A plugin that cannot be used: it fails to import, or its scores are not `[N]` finite float32 (one line)."""


@dataclasses.dataclass(frozen=True)
class GridContext:
    """What a method's default grid may depend on.

    Attributes:
      task: the environment's `ape_jax.tasks.Task` (e.g. FCA's α per task).
      n_train: transitions in the training split (e.g. DAgger's query budget).
      knobs: the methods' own settings as the sweep resolved them (`Method.knobs`, `--set METHOD.KNOB=...`, the
        presets' grids), `{method: its knobs record}`; a method not listed runs at its record's defaults
        (`knobs_of`).
    """

    task: Any
    n_train: int
    knobs: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def knobs_of(self, method: str) -> Any:
        """Method `method`'s own settings (`Method.knobs`): those the sweep was given, else its defaults."""
        return knobs_of(method, self.knobs)


@dataclasses.dataclass(frozen=True)
class LearnerContext:
    """What a method's learner factory may depend on.

    Attributes:
      cfg: the program's `ape_jax.learner.LearnerConfig`.
      env: the environment the policies are evaluated in.
      expert: the expert as `full observation -> action` (online methods query it).
      obs_mean, obs_std: the observation standardisation (None for images).
      n_train: transitions in the training split.
      knobs: the methods' own settings, as `GridContext.knobs` (`knobs_of`: a learner's static settings, e.g.
        PALR's `rows`).
    """

    cfg: Any
    env: Any
    expert: Callable[[jax.Array], jax.Array] | None
    obs_mean: Any
    obs_std: Any
    n_train: int
    knobs: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def knobs_of(self, method: str) -> Any:
        """Method `method`'s own settings (`Method.knobs`): those the sweep was given, else its defaults."""
        return knobs_of(method, self.knobs)


def knobs_of(method: str, given: Mapping[str, Any]) -> Any:
    """The `Method.knobs` record of `method`: `given[method]` where the sweep set one, else the defaults;
    `MethodError` for a method without knobs of its own."""
    record = get(method).knobs
    if record is None:
        raise MethodError(f"method {method!r} has no settings of its own (Method.knobs)")
    return given.get(method) or record()


Scores = Callable[[jax.Array, jax.Array, jax.Array], jax.Array]


@dataclasses.dataclass(frozen=True)
class Method:
    """One method: how its configurations are listed, made traced, trained, and reported.

    Attributes:
      name: the command line's and the results' name (`"ours-step"`).
      label: how tables and figures name it (`"Ours (step)"`).
      grid: `grid(GridContext) -> [settings]`, the hyperparameter settings it
        runs at by default, each a JSON-able dict of numbers (`{"thr": 0.1, "w": 5.0}`).
      hparams: `hparams(settings, lr, score_row) -> traced hyperparameters` of
        its learner (an `ape_jax.learner.Hparams` for the weighted learner);
        `score_row` is the row of the score table its weights read (0: APE).
      program: methods with the same program train in one compiled, vmapped
        program: `"grid"` is the weighted learner at the preset's history.
      history: observations the policy sees; None: the preset's.
      observation: what each of those observations is: None, the sweep's (`--obs`); `"full"`, the
        environment's full state (velocities included), built from the demonstrations' simulator
        state (`ape_jax.observations`), standardised with its own training statistics, and evaluated
        in the `obs="full"` environment (`bc-full`).
      learner: `learner(LearnerContext) -> ape_jax.learner.Learner`; None: the
        weighted learner (`ape_jax.learner.make_train`).
      score: `score(key, actions [N, A], t [N]) -> [N] float32`, the method's
        per-sample scores (a row of the score table); None: it reads the APE.
      online: whether it queries the expert during training (DAgger).
      role: `"reference"` (BC-SO, BC-OH), `"ours"`, `"baseline"` or `"plugin"`.
      module: the module that registered it.
      knobs: the method's own settings, a frozen dataclass whose defaults are the authors' (each field typed, as
        `--set METHOD.FIELD=VALUE` parses it; a `tuple[float, ...]` field is a grid axis its `grid` spans), which
        checks its values in `__post_init__` (`ValueError`, one line); None: it has none. Its grid and learner
        read the sweep's record with `ctx.knobs_of(name)`.
      runtime: `runtime(cfg, settings) -> ape_jax.evaluate.Runtime`: how its trained policies act where they are
        not `cfg.model()` on the history (action chunks with their ensemble, a composite); None: they are.
      reads: `reads(GridContext) -> method | None`: the method whose trained policies its runs read, each run
        its own seed's (Priming's prime: BC-SO's): the sweep trains that method's program first, refuses a sweep
        without it, and hands its policies to the stacked hyperparameters' `read(params)` (`read_trained`).
      refuses: `refuses(settings, obs) -> why | None`: why the method cannot run under a sweep's
        `ape_jax.pipeline.presets.Settings` and observation mode (RAP: without a history, or on images with an
        encoder other than `patch`), checked when the sweep's spec is made, before anything is collected or
        compiled; None: it runs anywhere.
    """

    name: str
    label: str
    grid: Callable[[GridContext], Sequence[Mapping[str, float]]]
    hparams: Callable[[Mapping[str, float], float, int], Any]
    program: str = "grid"
    history: int | None = None
    observation: str | None = None
    learner: Callable[[LearnerContext], Any] | None = None
    score: Scores | None = None
    online: bool = False
    role: str = "baseline"
    module: str = ""
    refuses: Callable[[Any, str], str | None] | None = None
    knobs: type | None = None
    runtime: Callable[[Any, Sequence[Mapping[str, float]]], Any] | None = None
    reads: Callable[[GridContext], str | None] | None = None

    def settings(self, ctx: GridContext) -> list[dict]:
        """The default grid as plain dicts of floats (what `results.json` records as `hparams`)."""
        return [{k: float(v) for k, v in dict(s).items()} for s in self.grid(ctx)]


_registry: dict[str, Method] = {}
_sequence: dict[str, int] = {}   # registration order
_builtin_modules: list[str] = []  # the built-in modules, in discovery (alphabetical) order
_builtins = "unloaded"  # -> "loading" -> "loaded"


def _ensure_builtins() -> None:
    global _builtins
    if _builtins != "unloaded":
        return
    _builtins = "loading"
    try:
        for package_name in BUILTIN_PACKAGES:
            package = importlib.import_module(package_name)
            for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
                if not info.name.startswith("_"):
                    _builtin_modules.append(f"{package_name}.{info.name}")
        for module in _builtin_modules:
            importlib.import_module(module)
    finally:
        _builtins = "loaded"


def register(method: Method) -> Method:
    """Adds `method` to the registry and returns it.

    Raises:
      MethodError: the name is taken or malformed, the role unknown, or
        another method of the same program trains with a different history,
        observation or learner.
    """
    _ensure_builtins()
    if not _NAME.match(method.name):
        raise MethodError(f"method name {method.name!r} must be lowercase letters, digits, '-', '_' or '.'")
    if method.name in _registry:
        other = _registry[method.name]
        raise MethodError(f"method {method.name!r} is already registered (by {other.module or 'a module'}); "
                          f"pick another name; registered: {', '.join(_registry)}")
    if method.role not in ROLES:
        raise MethodError(f"method {method.name!r}: unknown role {method.role!r}; valid: {', '.join(ROLES)}")
    if method.knobs is not None and not (dataclasses.is_dataclass(method.knobs)
                                         and method.knobs.__dataclass_params__.frozen):
        raise MethodError(f"method {method.name!r}: knobs must be a frozen dataclass, got {method.knobs!r}")
    if method.observation not in OBSERVATIONS:
        raise MethodError(f"method {method.name!r}: unknown observation {method.observation!r}; valid: "
                          f"{', '.join(map(str, OBSERVATIONS))}")
    for other in _registry.values():
        if other.program == method.program and ((other.history, other.learner, other.observation)
                                                != (method.history, method.learner, method.observation)):
            raise MethodError(f"method {method.name!r} trains in program {method.program!r} with another history, "
                              f"observation or learner than {other.name!r}; give it a program of its own")
    _registry[method.name] = method
    _sequence[method.name] = len(_sequence)
    return method


def get(name: str) -> Method:
    """The record of `name`; `MethodError` listing the registered names if there is none."""
    _ensure_builtins()
    if name not in _registry:
        raise MethodError(f"unknown method {name!r}; valid: {', '.join(names())}")
    return _registry[name]


def names(role: str | None = None) -> tuple[str, ...]:
    """Registered names in listing order (references, ours, baselines, plugins), optionally of one role."""
    _ensure_builtins()

    def rank(m: Method):  # built-ins by module (whatever order they were imported in), then registration
        module = _builtin_modules.index(m.module) if m.module in _builtin_modules else len(_builtin_modules)
        return ROLES.index(m.role), module, _sequence[m.name]

    return tuple(m.name for m in sorted(_registry.values(), key=rank) if role is None or m.role == role)


def default() -> tuple[str, ...]:
    """What the sweep trains when no methods are asked for: the references that read the sweep's observation and
    ours (the paper's grid). A method reading another observation (`bc-full`, the full state) is asked for by
    name: it needs an evaluation program of its own (another environment to compile), which the no-argument
    sweep does not pay."""
    return tuple(m for m in names("reference") if _registry[m].observation is None) + names("ours")


def shortcuts() -> dict[str, tuple[str, ...]]:
    """Words the command line expands: `all`, `baselines`, `default`, `plugins` (`all` includes `bc-full`)."""
    return {"all": names(), "baselines": names("baseline"), "default": default(), "plugins": names("plugin")}


def resolve(text: str | Sequence[str]) -> tuple[str, ...]:
    """A comma list (or sequence) of names and shortcuts as registered names, in the order given.

    Raises:
      MethodError: an unknown name, a name listed twice, or nothing at all.
    """
    words = [w.strip() for w in (text.split(",") if isinstance(text, str) else text) if w.strip()]
    short = shortcuts()
    out = tuple(m for w in words for m in short.get(w, (w,)))
    if not out:
        raise MethodError("no methods given")
    unknown = [m for m in out if m not in _registry]
    if unknown:
        raise MethodError(f"unknown method(s) {', '.join(unknown)}; valid: {', '.join(names())} "
                          f"(or {', '.join(short)})")
    if len(set(out)) != len(out):
        raise MethodError("a method is listed twice")
    return out


def run_key(seed: int, method: str, hparams: Mapping[str, float]) -> jax.Array:
    """The PRNG key of one run, from its identity alone: `fold_in(PRNGKey(seed), crc32(method, hparams))`.

    The same configuration gets the same initialisation and batches whatever
    else trains beside it, and in whatever order.
    """
    ident = method + "|" + ",".join(f"{k}={float(v)!r}" for k, v in sorted(hparams.items()))
    return jax.random.fold_in(jax.random.PRNGKey(seed), zlib.crc32(ident.encode()) & 0x7FFFFFFF)


def score_key(method: str) -> jax.Array:
    """The key a method's score function gets (from its name: the same scores whatever else runs)."""
    return run_key(0, method, {"score": 1.0})


# -- weighting methods: the plugin contract -----------------------------------------------------------------------

def weighting_hparams(kind: str) -> Callable[[Mapping[str, float], float, int], Any]:
    from ape_jax.learner import Hparams

    def hparams(settings: Mapping[str, float], lr: float, row: int):
        if kind == "step":
            return Hparams.make("step", lr=lr, thr=settings["thr"], w=settings["w"], source=row)
        if kind == "softmax":
            return Hparams.make("softmax", lr=lr, tau=settings["tau"], source=row)
        return Hparams.make("given", lr=lr, source=row)

    return hparams


def weighting_grid(kind: str, grid: Sequence[Mapping[str, float]] | None,
                   name: str = "") -> Callable[[GridContext], list[dict]]:
    """The grid of weighting method `name` of `kind`: `grid` where given, else its own settings' (`StepKnobs.grid`,
    `SoftmaxKnobs.taus`: `weighting_knobs`)."""
    keys = {"step": {"thr", "w"}, "softmax": {"tau"}, "given": set()}[kind]
    if grid is not None:
        grid = [dict(s) for s in grid]
        for s in grid:
            if set(s) != keys:
                raise MethodError(f"a {kind} weighting's grid settings have the keys {sorted(keys)}, got {sorted(s)}")
        return lambda ctx: grid
    if kind == "step":
        return lambda ctx: [{"thr": thr, "w": w} for thr, w in ctx.knobs_of(name).grid]
    if kind == "softmax":
        return lambda ctx: [{"tau": tau} for tau in ctx.knobs_of(name).taus]
    return lambda ctx: [{}]


def weighting_knobs(kind: str, grid: Sequence[Mapping[str, float]] | None) -> type | None:
    """The settings record of a weighting of `kind` whose grid is not fixed (`grid` None): `StepKnobs` or
    `SoftmaxKnobs`; None where it has none."""
    from ape_jax.weighting import SoftmaxKnobs, StepKnobs

    return None if grid is not None else {"step": StepKnobs, "softmax": SoftmaxKnobs}.get(kind)


def sharing(record: type) -> list[str]:
    """The registered methods whose settings are a `record` (e.g. every step weighting's `StepKnobs`), in
    registration order: what `experiments.sweep --step-grid` and the presets' grids set at once."""
    _ensure_builtins()
    return [n for n in sorted(_registry, key=_sequence.get)
            if _registry[n].knobs is not None and issubclass(_registry[n].knobs, record)]


def read_by(name: str, knobs: Mapping[str, Any]) -> str | None:
    """The method whose trained policies method `name`'s runs read under the methods' settings `knobs`
    (`Method.reads`), or None."""
    method = get(name)
    return method.reads(GridContext(task=None, n_train=0, knobs=knobs)) if method.reads is not None else None


def unread(name: str, knobs: Mapping[str, Any], names: Sequence[str]) -> str | None:
    """Why method `name` cannot train among the methods `names` under the methods' settings `knobs`: it reads the
    trained policies of a method not among them (`Method.reads`); None where it can."""
    read = read_by(name, knobs)
    if read is None or read in names:
        return None
    return f"{name} reads the trained policies of {read}: add {read} to --methods, or change {name}'s settings"


def read_trained(hparams: Any, runs: Sequence[Any], read: str, source_runs: Sequence[Any], source_params: Any) -> Any:
    """`hparams` (stacked over `runs`) given the trained policies of method `read` (`Method.reads`): each run gets
    the policy of `read`'s run of its own seed, from a program's runs `source_runs` and their policies
    `source_params` (leaves `[len(source_runs), ...]`).

    Raises:
      MethodError: a run's seed has no run of `read` (one line).
    """
    index = {r.seed: i for i, r in enumerate(source_runs) if r.method == read}
    missing = sorted({r.seed for r in runs} - set(index))
    if missing:
        raise MethodError(f"{runs[0].method} reads {read}'s policies, which has no run of seed(s) {missing}")
    take = np.asarray([index[r.seed] for r in runs])
    return hparams.read(jax.tree.map(lambda x: jnp.asarray(x)[take], source_params))


def weighting(name: str, kind: str = "step", grid: Sequence[Mapping[str, float]] | None = None,
              label: str | None = None, *, role: str = "plugin") -> Callable[[Scores], Scores]:
    """Registers a per-sample score function as a weighting method of the grid program (a decorator).

    Args:
      name: the method's name on the command line and in results.
      kind: `"step"` (ranked, top THR × W), `"softmax"` (minibatch softmax at
        temperature τ) or `"given"` (the scores are the weights, >= 0).
      grid: the settings it runs at, e.g. `[{"thr": 0.1, "w": 5.0}]`; default:
        its own settings (`--set NAME.grid=...` for `"step"`, `NAME.taus=...`
        for `"softmax"`, the paper's grids unless set; the presets' and
        `--step-grid`/`--softmax-grid` set every such weighting's), or one
        setting `{}` (`"given"`).
      label: its name in tables and figures (default: `name`).
      role: `"plugin"` for user modules; the built-in baselines say `"baseline"`.

    The decorated function is `score(key, actions [N, A] float32, t [N] int32)
    -> [N] float32`, called once per sweep on the training split, outside
    `jit` (it may use NumPy); it is returned unchanged.
    """
    if kind not in WEIGHTING_KINDS:
        raise MethodError(f"method {name!r}: unknown weighting kind {kind!r}; valid: {', '.join(WEIGHTING_KINDS)}")
    make_grid = weighting_grid(kind, grid, name)

    def decorate(fn: Scores) -> Scores:
        register(Method(name=name, label=label or name, grid=make_grid, hparams=weighting_hparams(kind),
                        score=_checked(name, kind, fn), role=role, module=getattr(fn, "__module__", "") or "",
                        knobs=weighting_knobs(kind, grid)))
        return fn

    return decorate


def _checked(name: str, kind: str, fn: Scores) -> Scores:
    """`fn` with its output refused (`PluginError`, naming the method) unless it is `[N]` finite float32."""

    def score(key: jax.Array, actions: jax.Array, t: jax.Array) -> jax.Array:
        n = int(np.shape(actions)[0])
        try:
            out = fn(key, actions, t)
        except Exception as e:  # noqa: BLE001 - a user's function may raise anything; name it and stop
            raise PluginError(f"method {name!r}: its score function raised {type(e).__name__}: {e}") from e
        dtype = getattr(out, "dtype", None)
        if np.shape(out) != (n,):
            raise PluginError(f"method {name!r}: its score function returned shape {tuple(np.shape(out))}, "
                              f"expected ({n},) (one score per training sample)")
        if dtype != np.float32:
            raise PluginError(f"method {name!r}: its score function returned dtype {dtype}, expected float32")
        out = jnp.asarray(out)
        if not bool(jnp.all(jnp.isfinite(out))):
            raise PluginError(f"method {name!r}: its score function returned "
                              f"{int(jnp.sum(~jnp.isfinite(out)))} non-finite scores")
        if kind == "given" and bool(jnp.any(out < 0)):
            raise PluginError(f"method {name!r}: a 'given' weighting's scores are its weights and must be >= 0")
        return out

    return score


def load_plugins(modules: Sequence[str]) -> list[str]:
    """Imports each plugin module (by dotted name, from `PYTHONPATH`); returns the names they registered.

    Raises:
      PluginError: a module fails to import, registers nothing, or registers
        a name that is taken (the message names the module).
    """
    added = []
    for module in modules:
        mine = [m for m in names() if _registry[m].module == module]
        if mine:  # imported and registered already (a second sweep in one process)
            added += mine
            continue
        before = set(names())
        try:
            loaded = sys.modules.get(module)  # imported before, its registrations undone by `scratch`
            importlib.reload(loaded) if loaded is not None else importlib.import_module(module)
        except MethodError as e:
            raise PluginError(f"plugin {module!r}: {e}") from e
        except Exception as e:  # noqa: BLE001 - a plugin may fail any way; say which and how
            raise PluginError(f"plugin {module!r} failed to import: {type(e).__name__}: {e}") from e
        new = [m for m in names() if m not in before]
        if not new:
            raise PluginError(f"plugin {module!r} registered no method (decorate a score function with "
                              "@ape_jax.methods.weighting(NAME))")
        added += new
    return added


@contextlib.contextmanager
def scratch() -> Iterator[None]:
    """Registrations made inside are undone on exit (for tests and notebooks)."""
    _ensure_builtins()
    saved, sequence = dict(_registry), dict(_sequence)
    try:
        yield
    finally:
        _registry.clear()
        _registry.update(saved)
        _sequence.clear()
        _sequence.update(sequence)
