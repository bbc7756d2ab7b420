"""The command line that gives recorded settings: `arguments(env, obs, settings)` -> the sweep's `--preset`,
`--protocol`, `--recipe`, `--smoke` and `--set` arguments under which today's `presets.resolve` gives them (a
results file's settings replayed into a new folder).

    args = arguments("hopper", "pos", Settings.from_json(results["settings"], preset=results["preset"]))
"""

from __future__ import annotations

from collections.abc import Sequence

from ape_jax import tasks
from ape_jax.pipeline import method_knobs
from ape_jax.pipeline.hints import check
from ape_jax.pipeline.presets import SECTIONS, Settings, default_recipe, fields, format_set, resolve


def arguments(env: str, obs: str, target: Settings, methods: Sequence[str] | None = None) -> list[str]:
    """The sweep's arguments (`--preset`, `--protocol`, `--recipe`, `--smoke`, `--set`) under which `resolve`
    gives `target`'s records: the command line of a results file that records its settings but not its command
    (a sweep run from Python). Only what differs from the preset's, the protocol's and the recipe's own values
    is set; `methods` (the methods the file ran): only their own settings (`settings.knobs`) are set.

    Raises:
      SettingsError: no arguments give `target` (its preset, protocol or recipe is no longer known).
    """
    proto = target.protocol.name
    args = ["--preset", target.preset]
    if proto != tasks.get(env).protocol(None, obs).name:
        args += ["--protocol", proto]
    if target.recipe.name != default_recipe(target.protocol, obs):
        args += ["--recipe", target.recipe.name]
    if target.smoke:
        args.append("--smoke")

    def differences(settings: Settings, skip: tuple[str, ...] = ()) -> list[str]:
        return [format_set(section, f, getattr(getattr(target, section), f)) for section in SECTIONS
                for f in fields(section) if f not in skip
                and getattr(getattr(settings, section), f) != getattr(getattr(target, section), f)]

    def rebuild(sets: list[str]) -> Settings:
        return resolve(env, obs, proto, target.preset, target.recipe.name, sets=sets, smoke=target.smoke)

    # eval_at last: a changed budget.iterations trims the preset's points by itself (`resolve`)
    sets = differences(rebuild([]), skip=("eval_at",))
    sets += differences(rebuild(sets))
    # the methods' own settings over the preset's (its grids), of the methods run where `methods` names them
    sets += [s for s in method_knobs.differences(target.knobs, rebuild(sets).knobs)
             if methods is None or s.partition(".")[0] in methods]
    check(not differences(rebuild(sets)), f"no --set gives the recorded settings of {env} ({obs})")
    return args + [x for item in sets for x in ("--set", item)]
