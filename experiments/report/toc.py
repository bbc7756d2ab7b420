"""A markdown file's table of contents, generated: its `##` headings as GitHub anchor links, `###` nested.

    refresh(text)   # the block between `<!-- toc:start -->` and `<!-- toc:end -->` rebuilt from text's headings

`experiments.report --out FILE` calls `refresh` after writing the report section, so BENCHMARKS.md's contents
follow its headings; a file without both markers is left without one. The report's many per-group headings
("Hopper, `pos` observations, protocol fca: every configuration") are collapsed into one nested bullet of
inline links, so the contents stay short.

Anchors follow GitHub's rule for a heading's rendered text: lowercased; every character dropped but letters,
marks, decimal and letter numbers, connector punctuation (`_`), hyphens and spaces; spaces become hyphens; the
second heading with a given anchor gets `-1`, the third `-2`. So `τ` stays, `×`, `−`, `§` and backticks go.
Only ATX headings (`## Title`) count, and none inside fenced code blocks.
"""

from __future__ import annotations

import dataclasses
import re
import unicodedata

START, END = "<!-- toc:start -->", "<!-- toc:end -->"
EVERY_CONFIGURATION = ": every configuration"   # the report's per-group headings end so (`sections.detail`)

_ATX = re.compile(r"^ {0,3}(#{1,6})(?:[ \t]+(.*?))?[ \t]*$")
_CLOSING = re.compile(r"(?:^|[ \t]+)#+$")                    # an optional closing sequence, `## Title ##`
_FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
_LINK = re.compile(r"!?\[([^\]]*)\]\([^)]*\)")               # a link or image renders as its text
_KEPT_CATEGORIES = ("Nd", "Nl", "Pc")                         # with every letter (L*) and mark (M*)


@dataclasses.dataclass(frozen=True)
class Heading:
    """One heading: `level` 1–6, `text` as written (inline code kept), `anchor` unique within its file."""

    level: int
    text: str
    anchor: str


def slug(text: str) -> str:
    """The anchor GitHub gives a heading with this markdown text, before duplicates are numbered."""
    parts = _LINK.sub(r"\1", text).split("`")
    # outside code spans `_` at a word's edge is emphasis, not text; inside them everything is text
    rendered = "".join(part if i % 2 else re.sub(r"(?<!\w)_+|_+(?!\w)", "", part) for i, part in enumerate(parts))
    kept = (c for c in rendered.lower()
            if c in "- " or unicodedata.category(c)[0] in "LM" or unicodedata.category(c) in _KEPT_CATEGORIES)
    return "".join(kept).replace(" ", "-")


def headings(markdown: str) -> list[Heading]:
    """Every ATX heading of `markdown` outside fenced code, in order, each with its unique GitHub anchor."""
    found: list[Heading] = []
    seen: dict[str, int] = {}
    fence = None
    for line in markdown.splitlines():
        opened = _FENCE.match(line)
        if fence is not None:
            # a fence closes on a run of its own character at least as long, with nothing after it
            if opened and opened.group(1)[0] == fence[0] and len(opened.group(1)) >= len(fence) \
                    and not line.strip().lstrip(fence[0]):
                fence = None
            continue
        if opened:
            fence = opened.group(1)
            continue
        match = _ATX.match(line)
        if match is None:
            continue
        text = _CLOSING.sub("", match.group(2) or "").strip()
        base = anchor = slug(text)
        while anchor in seen:
            seen[base] += 1
            anchor = f"{base}-{seen[base]}"
        seen[anchor] = 0
        found.append(Heading(len(match.group(1)), text, anchor))
    return found


def _link(label: str, anchor: str) -> str:
    return "[" + label.replace("[", "\\[").replace("]", "\\]") + f"](#{anchor})"


def build(markdown: str) -> str:
    """The table of contents of `markdown`: one bullet per `##` heading, its `###` headings nested under it.

    Under each `##` heading, the `###` headings that end in ": every configuration" become one nested bullet,
    "Every configuration: " and a link per group, where the first of them stood (a label that repeats gets
    " (2)", " (3)").

    Returns:
      the bullets, one per line, each line ending in a newline; "" for a file without `##` or `###` headings.
    """
    lines: list[str] = []
    groups: list[str] = []
    labels: dict[str, int] = {}
    at = 0

    def flush():
        if groups:
            lines.insert(at, "  - Every configuration: " + ", ".join(groups))
            groups.clear()
            labels.clear()

    for heading in headings(markdown):
        if heading.level == 2:
            flush()
            lines.append(f"- {_link(heading.text, heading.anchor)}")
        elif heading.level == 3 and heading.text.endswith(EVERY_CONFIGURATION):
            label = heading.text[: -len(EVERY_CONFIGURATION)]
            labels[label] = labels.get(label, 0) + 1
            if not groups:
                at = len(lines)
            groups.append(_link(label if labels[label] == 1 else f"{label} ({labels[label]})", heading.anchor))
        elif heading.level == 3:
            lines.append(f"  - {_link(heading.text, heading.anchor)}")
    flush()
    return "".join(line + "\n" for line in lines)


def refresh(markdown: str) -> str:
    """`markdown` with the block between `<!-- toc:start -->` and `<!-- toc:end -->` replaced by `build`'s
    table of contents; without both markers (in that order), `markdown` unchanged."""
    start = markdown.find(START)
    end = markdown.find(END, start + len(START)) if start >= 0 else -1
    if start < 0 or end < 0:
        return markdown
    return markdown[: start + len(START)] + "\n" + build(markdown) + markdown[end:]
