"""mkdocs hook: links from the docs to files of the repository outside `docs/`.

The pages are written to read on a repository host too, so they link files beside them
by relative paths (`../BENCHMARKS.md`, `../../figures/curves.png`). mkdocs knows only the
files under `docs/` and would report each such link as missing. This hook copies every
repository file a page links into the site under `repository/` (a linked Markdown file
becomes a page, whose own links are followed the same way) and rewrites the links to
point there. A link to a file that does not exist is left as written, so
`mkdocs build --strict` fails on it like on any other broken link.

Every figure opens full size on a click: the hook wraps each image of a page that is not
already inside a link in a link to the image itself (the figures are drawn wider than the
content column, which shows them scaled down).

Registered in `mkdocs.yml` (`hooks:`); `exclude_docs` keeps this file out of the site.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path
from urllib.parse import unquote, urlsplit

from mkdocs.structure.files import File, Files

PREFIX = "repository"  # where the site keeps the repository's files

# [text](target) and ![alt](target "title"): group 2 is the target
_INLINE = re.compile(r"(!?\[[^\]\n]*\]\()([^)\s]+)")
# [label]: target, a reference definition at the start of a line
_REFERENCE = re.compile(r"(^[ ]{0,3}\[[^\]\n]+\]:[ \t]*)(\S+)", re.MULTILINE)
# in a page's HTML, a link (left as it is, images and all) or an image outside one
_LINK_OR_IMAGE = re.compile(r"<a\b[^>]*>.*?</a>|<img\b[^>]*>", re.DOTALL)
_SRC = re.compile(r"""\bsrc=("[^"]*"|'[^']*')""")


def _targets(markdown: str):
    """Yields (match, target) for every link target in `markdown`."""
    for pattern in (_INLINE, _REFERENCE):
        for match in pattern.finditer(markdown):
            yield match, match.group(2)


def _repo_path(target: str, page_repo_path: str) -> str | None:
    """The repository path (posix, relative to the root) that `target` names from the page at
    `page_repo_path`, or None for external, absolute and same-page links and paths above the root."""
    parts = urlsplit(target)
    if parts.scheme or parts.netloc or not parts.path or parts.path.startswith("/"):
        return None
    path = posixpath.normpath(posixpath.join(posixpath.dirname(page_repo_path), unquote(parts.path)))
    return None if path == ".." or path.startswith("../") else path


def _roots(config) -> tuple[Path, str]:
    root = Path(config.config_file_path).resolve().parent
    return root, Path(config.docs_dir).resolve().relative_to(root).as_posix()


def _page_repo_path(src_uri: str, docs: str) -> str:
    if src_uri.startswith(PREFIX + "/"):
        return src_uri[len(PREFIX) + 1:]
    return posixpath.join(docs, src_uri)


def on_files(files: Files, config) -> Files:
    """Adds each repository file outside the docs that a page links (transitively through
    linked Markdown files) as `repository/<path>`."""
    root, docs = _roots(config)
    queue = [f for f in files.documentation_pages()]
    while queue:
        page = queue.pop()
        page_path = _page_repo_path(page.src_uri, docs)
        for _, target in _targets(page.content_string):
            path = _repo_path(target, page_path)
            if path is None or path == docs or path.startswith(docs + "/") or not (root / path).is_file():
                continue
            src_uri = f"{PREFIX}/{path}"
            if files.get_file_from_path(src_uri) is None:
                added = File.generated(config, src_uri, abs_src_path=str(root / path))
                files.append(added)
                if added.is_documentation_page():
                    queue.append(added)
    return files


def on_page_markdown(markdown: str, page, config, files: Files) -> str:
    """Rewrites the page's links to repository files to their copies under `repository/`, and the
    copied pages' links to `docs/...` to the docs' own pages."""
    _, docs = _roots(config)
    page_uri = page.file.src_uri
    page_path = _page_repo_path(page_uri, docs)

    def site_uri(path: str) -> str | None:
        if path.startswith(docs + "/"):
            return path[len(docs) + 1:]
        uri = f"{PREFIX}/{path}"
        return uri if files.get_file_from_path(uri) is not None else None

    edits = []
    for match, target in _targets(markdown):
        path = _repo_path(target, page_path)
        uri = None if path is None else site_uri(path)
        if uri is None:
            continue
        parts = urlsplit(target)
        new = posixpath.relpath(uri, posixpath.dirname(page_uri) or ".")
        new += (f"?{parts.query}" if parts.query else "") + (f"#{parts.fragment}" if parts.fragment else "")
        if new != target:
            edits.append((match.start(2), match.end(2), new))
    for start, end, new in sorted(edits, reverse=True):
        markdown = markdown[:start] + new + markdown[end:]
    return markdown


def on_page_content(html: str, page, config, files: Files) -> str:
    """Wraps each image of the page's HTML that no link holds in a link to the image's own file."""

    def link(match: re.Match) -> str:
        found = _SRC.search(match.group(0))
        if match.group(0).startswith("<a") or found is None:
            return match.group(0)
        return f'<a href={found.group(1)} class="full-size">{match.group(0)}</a>'

    return _LINK_OR_IMAGE.sub(link, html)
