"""MkDocs hook: links from the documentation to files of the repository outside docs/.

The pages link to repository files the way GitHub reads them, relative to the page
(`../BENCHMARKS.md`, `../examples/01_demo_to_posterior.py`), so the same links work when the
Markdown is read on GitHub. MkDocs knows only the files under docs/ and would call those
links broken. This hook mirrors each repository file that a page links to into the site under
`repo/` (a Markdown file becomes a page there, rendered; any other file is copied as it is) and
points the link at the mirror. A link to a repository file that does not exist is left alone,
so `mkdocs build --strict` reports it as broken.
"""
from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File, InclusionLevel

MIRROR = "repo"
LINK = re.compile(r"(\]\()([^()\s]+)((?:\s+\"[^\"]*\")?\))")   # [text](target) and ![alt](target)
FENCE = re.compile(r"^\s*(```|~~~)")


def _root(config) -> Path:
    return Path(config.config_file_path).resolve().parent


def _targets(text: str):
    """Each link target of a Markdown text outside fenced code: (match, path, fragment)."""
    fenced = False
    for line in text.splitlines(keepends=True):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if fenced:
            continue
        for m in LINK.finditer(line):
            target = m.group(2)
            if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith(("#", "/")):
                continue
            path, _, fragment = target.partition("#")
            yield m, path, fragment


def _resolve(source: Path, path: str) -> Path:
    return (source.parent / path).resolve()


def _outside(config, target: Path) -> str | None:
    """The repository-relative path of a file outside docs/, or None (inside docs/, missing,
    or outside the repository)."""
    docs, root = Path(config.docs_dir).resolve(), _root(config)
    if target.is_relative_to(docs) or not target.is_relative_to(root) or not target.is_file():
        return None
    return target.relative_to(root).as_posix()


def on_files(files, config):
    """Add a mirror of every repository file that a page (or a mirrored page) links to."""
    root = _root(config)
    queue = [Path(f.abs_src_path) for f in files.documentation_pages()]
    mirrored: set[str] = set()
    while queue:
        source = queue.pop()
        for _, path, _ in _targets(source.read_text(encoding="utf-8")):
            if not path:
                continue
            rel = _outside(config, _resolve(source, path))
            if rel is None or rel in mirrored:
                continue
            mirrored.add(rel)
            files.append(File.generated(config, f"{MIRROR}/{rel}", abs_src_path=str(root / rel),
                                        inclusion=InclusionLevel.NOT_IN_NAV))
            if rel.endswith(".md"):
                queue.append(root / rel)
    return files


def on_page_markdown(markdown, page, config, files):
    """Point links to repository files at their mirrors (and, in a mirrored page, links into
    docs/ at the pages), relative to the page."""
    docs = Path(config.docs_dir).resolve()
    source = Path(page.file.abs_src_path).resolve()
    here = posixpath.dirname(page.file.src_uri)
    mirrored_page = not source.is_relative_to(docs)

    def rewrite(m, path, fragment):
        target = _resolve(source, path)
        if target.is_relative_to(docs):
            if not mirrored_page:
                return None
            uri = target.relative_to(docs).as_posix()
        else:
            rel = _outside(config, target)
            if rel is None:
                return None            # missing: MkDocs reports the link as not found
            uri = f"{MIRROR}/{rel}"
        new = posixpath.relpath(uri, here or ".")
        return m.group(1) + new + ("#" + fragment if fragment else "") + m.group(3)

    out, fenced = [], False
    for line in markdown.splitlines(keepends=True):
        if FENCE.match(line):
            fenced = not fenced
        elif not fenced:
            edits = [(m.span(), rewrite(m, p, f)) for m, p, f in _targets(line) if p]
            for (start, end), new in reversed(edits):
                if new is not None:
                    line = line[:start] + new + line[end:]
        out.append(line)
    return "".join(out)
