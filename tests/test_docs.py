"""The documentation site: mkdocs.yml's nav names pages that exist, and the hook that carries the pages' links to
repository files (`docs/hooks.py`) copies what they link and leaves a broken link for `--strict` to refuse."""

import importlib.util
import logging
import pathlib

import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]


class _Loader(yaml.SafeLoader):
    """mkdocs.yml without its `!!python/...` tags (they name the toc's slug function), so no docs extra is needed."""


_Loader.add_multi_constructor("tag:yaml.org,2002:python/", lambda loader, suffix, node: None)


def _nav_files(nav) -> list[str]:
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, dict):
        return [f for value in nav.values() for f in _nav_files(value)]
    return [f for item in nav for f in _nav_files(item)]


def test_every_page_in_the_nav_exists_and_every_page_is_in_the_nav():
    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=_Loader)
    docs = ROOT / config["docs_dir"]
    pages = _nav_files(config["nav"])
    assert [p for p in pages if not (docs / p).is_file()] == []
    assert len(pages) == len(set(pages))
    # a page left out of the nav is reachable only by a link: the nav lists every page but the generated ones
    written = {p.relative_to(docs).as_posix() for p in docs.rglob("*.md")}
    generated = {p for p in written if p.startswith("results/") and p != "results/index.md"}
    assert written - generated - set(pages) == set()


@pytest.fixture
def site(tmp_path):
    """A tiny repository: a docs page linking a repository page, a figure and a missing file."""
    pytest.importorskip("mkdocs")
    (tmp_path / "docs").mkdir()
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"\x89PNG")
    (tmp_path / "docs" / "index.md").write_text(
        "# Home\n\n[notes](../NOTES.md#part-two) ![a figure](../figures/a.png)\n")
    (tmp_path / "NOTES.md").write_text("# Notes\n\n## Part two\n\nBack [home](docs/index.md#home).\n")
    (tmp_path / "mkdocs.yml").write_text(
        f"site_name: t\ndocs_dir: docs\nhooks:\n  - {ROOT / 'docs' / 'hooks.py'}\n"
        "validation:\n  anchors: warn\nnav:\n  - Home: index.md\n")
    return tmp_path


def _build(site, caplog):
    from mkdocs.commands.build import build
    from mkdocs.config import load_config

    config = load_config(str(site / "mkdocs.yml"), site_dir=str(site / "site"))
    with caplog.at_level(logging.WARNING):
        build(config)
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_links_to_repository_files_are_copied_and_rewritten(site, caplog):
    assert _build(site, caplog) == []
    assert (site / "site" / "repository" / "figures" / "a.png").read_bytes() == b"\x89PNG"
    index = (site / "site" / "index.html").read_text()
    assert 'href="repository/NOTES/#part-two"' in index and 'src="repository/figures/a.png"' in index
    # the copied page's own link back into the docs points at the docs' page
    assert 'href="../../#home"' in (site / "site" / "repository" / "NOTES" / "index.html").read_text()
    # the figure opens full size on a click: a link to its own file
    assert ('<a href="repository/figures/a.png" class="full-size"><img alt="a figure" '
            'src="repository/figures/a.png"') in index


def test_an_image_already_in_a_link_is_left_as_it_is(site, caplog):
    (site / "docs" / "index.md").write_text("# Home\n\n[![a figure](../figures/a.png)](https://example.org)\n")
    assert _build(site, caplog) == []
    index = (site / "site" / "index.html").read_text()
    assert '<a href="https://example.org"><img' in index and "full-size" not in index


def test_a_link_to_a_missing_file_or_anchor_warns(site, caplog):
    (site / "docs" / "index.md").write_text("# Home\n\n[gone](../GONE.md) [notes](../NOTES.md#no-such-part)\n")
    warnings = _build(site, caplog)
    assert any("'../GONE.md'" in w and "not found" in w for w in warnings), warnings
    assert any("does not contain an anchor '#no-such-part'" in w for w in warnings), warnings


def test_the_hook_resolves_paths_within_the_repository_only():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    pytest.importorskip("mkdocs")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    assert hooks._repo_path("../BENCHMARKS.md#x", "docs/speed.md") == "BENCHMARKS.md"
    assert hooks._repo_path("../../figures/a%20b.png", "docs/results/hopper.md") == "figures/a b.png"
    assert hooks._repo_path("../../outside.md", "docs/speed.md") is None
    assert hooks._repo_path("https://example.org/a.md", "docs/speed.md") is None
    assert hooks._repo_path("#anchor", "docs/speed.md") is None
