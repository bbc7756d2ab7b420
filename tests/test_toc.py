"""`experiments.report.toc`: GitHub anchors, the nested contents, fenced code ignored, the block refreshed in place."""

import pytest

from experiments.report import toc


@pytest.mark.parametrize("text, anchor", [
    ("The reproduction in brief (issues 8, 16 and 24)", "the-reproduction-in-brief-issues-8-16-and-24"),
    ("The paper's recipe: the FCA code's policy", "the-papers-recipe-the-fca-codes-policy"),
    ("Differences over seeds: Ours − BC-OH, and BC-OH − BC-SO", "differences-over-seeds-ours--bc-oh-and-bc-oh--bc-so"),
    ("Hopper, `pos` observations, protocol fca-fs2", "hopper-pos-observations-protocol-fca-fs2"),
    ("`budget.width` and `snake_case`", "budgetwidth-and-snake_case"),
    ("Softmax τ 0.1 × W 5", "softmax-τ-01--w-5"),                  # letters kept (τ), symbols dropped (×)
    ("Frame skip 1 – 4, 64×64 frames", "frame-skip-1--4-6464-frames"),  # the en dash is punctuation, not a hyphen
    ("Sensitivity (the supplement's §4)", "sensitivity-the-supplements-4"),
    ("Ωmega Ünïcode, x²", "ωmega-ünïcode-x"),                      # lowercased; ² is no decimal digit
    ("A [linked](https://example.org/a_b) word", "a-linked-word"),
    ("_emphasis_ and *stars* beside snake_case", "emphasis-and-stars-beside-snake_case"),
])
def test_slug_follows_githubs_rule(text, anchor):
    assert toc.slug(text) == anchor


def test_headings_number_duplicates_and_skip_fenced_code_and_non_headings():
    markdown = "\n".join([
        "# Title", "## A", "### A", "## A-1 ##", "## A", "#not-a-heading", "    ## indented code",
        "```python", "## inside backticks", "~~~", "## still inside: a ~~~ does not close ```", "```",
        "~~~~", "## inside tildes", "```", "~~~~", "   ### B   ", "####### seven is too many",
    ])
    found = [(h.level, h.text, h.anchor) for h in toc.headings(markdown)]
    assert found == [(1, "Title", "title"), (2, "A", "a"), (3, "A", "a-1"), (2, "A-1", "a-1-1"), (2, "A", "a-2"),
                     (3, "B", "b")]


MARKDOWN = """# Benchmarks

<!-- toc:start -->
stale
<!-- toc:end -->

## Results `fca` × τ

### Table one
### Hopper, `pos`: every configuration
### Walker2d: every configuration
### Hopper, `pos`: every configuration

```
## not a heading
```

## Reliability
#### too deep for the contents
### Table one
"""

CONTENTS = (
    "- [Results `fca` × τ](#results-fca--τ)\n"
    "  - [Table one](#table-one)\n"
    "  - Every configuration: [Hopper, `pos`](#hopper-pos-every-configuration), "
    "[Walker2d](#walker2d-every-configuration), [Hopper, `pos` (2)](#hopper-pos-every-configuration-1)\n"
    "- [Reliability](#reliability)\n"
    "  - [Table one](#table-one-1)\n"
)


def test_build_nests_level_three_and_collapses_every_configuration_into_one_bullet():
    assert toc.build(MARKDOWN) == CONTENTS
    assert toc.build("# Only a title\n\nprose\n") == ""


def test_refresh_replaces_only_the_block_and_is_idempotent():
    fresh = toc.refresh(MARKDOWN)
    assert fresh == MARKDOWN.replace("stale\n", CONTENTS)
    assert toc.refresh(fresh) == fresh


@pytest.mark.parametrize("markdown", [
    "# T\n\n## A\n",                                          # no markers
    "# T\n\n<!-- toc:start -->\n\n## A\n",                    # only the start
    "# T\n\n<!-- toc:end -->\nx\n<!-- toc:start -->\n## A\n",  # in the wrong order
])
def test_refresh_leaves_a_text_without_both_markers_as_it_was(markdown):
    assert toc.refresh(markdown) == markdown
