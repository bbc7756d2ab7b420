"""The results page's driving section, after its headline: per driving task, the verdict in numbers
(`analysis.driving_verdicts`), the figure of its state's first table and links to every page with its driving
tables."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report import figures
from experiments.report.analysis import CAMERA, DrivingVerdict, driving_table, driving_verdicts, file_stem, is_rate
from experiments.report.sections.common import Context, Section, page_name, page_title
from experiments.report.sections.task_metrics import comparison_text, driving_name


def _value(x: float, rate: bool) -> str:
    return f"{x:.1f}%" if rate else f"{x:.2f}"


def verdict_text(v: DrivingVerdict, ctx: Context) -> str:
    """The verdict's numbers in two sentences: BC-OH and BC-SO in the state's first table with their difference and
    the copycat counts over every state table; then the best camera policy learned from pixels and, for a task with a
    perception card, through its pretrained encoder (or that none ran)."""
    task, head = tasks.get(v.env), ctx.merged[v.headline]
    rate, metric = is_rate(head), head.metric
    names = {"bc-oh": "BC-OH", "bc-so": "BC-SO"}
    means = ", ".join(f"{names[k]} {_value(v.means[k], rate)}" for k in names if k in v.means)
    text = (f"{task.title} on the state (`--obs {v.headline.obs}`), {driving_name(driving_table(head))}: {metric} "
            f"{means}"
            + (f" ({comparison_text(v.history)})" if v.history else "")
            + f"; copycat over every state table: {v.copycats} of {v.policies} policies by the first verdict, "
              f"{v.controlled} of {v.judged} by the controlled one.")
    if v.camera is None and v.perceived is None:
        return text
    text += f" The camera (`--obs {CAMERA}`): learned from pixels, " + (
        f"at most {_value(v.camera, rate)} {metric} in any table" if v.camera is not None else "not run")
    if task.perception is not None:
        text += "; through the task's pretrained encoder (docs/perception.md), " + (
            f"at most {_value(v.perceived, rate)}" if v.perceived is not None else "not run yet")
    return text + "."


def driving_lead(ctx: Context) -> list[Section]:
    """"Driving: TASK" per verdict (`analysis.driving_verdicts`): `verdict_text`, the figure of the headline group's
    table (the task page's, drawn once: `figures.driving_figure`) and a link to each page with the task's driving
    tables; nothing without a driving group of a state."""
    out = []
    for v in driving_verdicts(ctx.merged):
        head = ctx.merged[v.headline]
        pages = dict.fromkeys((k.env, k.obs) for k in (*v.states, *v.cameras))
        links = ", ".join(f"[{page_title(env, obs)}]({page_name(env, obs)})" for env, obs in pages)
        out.append(Section(f"Driving: {tasks.get(v.env).title}", verdict_text(v, ctx), [
            *ctx.figure(f"driving-{file_stem(head)}.png", f"{head.title}: {head.metric} and stuck per method",
                        lambda m=head: figures.driving_figure(m)),
            f"Every driving table: {links}.", ""]))
    return out
