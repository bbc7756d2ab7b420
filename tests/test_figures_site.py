"""The documentation site leads with the answer: the home page opens with the README's answer table and the headline
figure, the results page with the paper's-budget table, and the site's stylesheet keeps wide tables in view."""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _section(markdown: str, heading: str) -> str:
    """The text under `## heading`, up to the next `## ` heading."""
    start = markdown.index(f"\n## {heading}\n")
    end = markdown.find("\n## ", start + 1)
    return markdown[start:end if end >= 0 else None]


def _table(text: str) -> list[str]:
    """The lines of the first markdown table in `text`."""
    lines = text.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("|"))
    rest = lines[first:]
    return rest[:next((i for i, line in enumerate(rest) if not line.startswith("|")), len(rest))]


def test_the_home_page_opens_with_the_readmes_answer_table_and_the_headline_figure():
    home = (ROOT / "docs" / "index.md").read_text()
    readme = (ROOT / "README.md").read_text()
    headings = re.findall(r"^## (.+)$", home, flags=re.M)
    assert headings[0] == "The answer so far", headings
    answer = _section(home, "The answer so far")
    assert _table(answer) == _table(_section(readme, "The answer so far"))   # the same numbers, kept in step
    assert "](../figures/paper-budget.png)" in answer and (ROOT / "figures" / "paper-budget.png").exists()


def test_the_results_page_opens_with_the_papers_budget_table():
    page = (ROOT / "docs" / "results" / "index.md").read_text()
    block = page[page.index("<!-- report:start -->"):]
    assert re.findall(r"^## (.+)$", block, flags=re.M)[0] == "The paper's budget with the paper's recipe"
    assert _table(block)[0].startswith("| task | method | seeds | % of expert at 30,000 |")


def test_the_site_wraps_wide_tables_to_the_content_column():
    config = (ROOT / "mkdocs.yml").read_text()
    sheets = re.findall(r"^extra_css:\n((?:  - .+\n)+)", config, flags=re.M)
    assert sheets, "mkdocs.yml names no extra_css"
    names = [line.strip()[2:] for line in sheets[0].splitlines()]
    css = "".join((ROOT / "docs" / name).read_text() for name in names)
    # Material's cells are padded 1.25em a side with headings at least 5rem wide: the stylesheet takes both back
    assert re.search(r"min-width:\s*0", css) and re.search(r"padding:\s*0\.\d+em", css)
