#!/usr/bin/env python3
"""Fail on broken links in the README and the user guide (docs/).

Two passes, both offline (web links are not followed):

1. Markdown sources (README.md and docs/src/**/*.md): every relative link or image must name a file
   that exists (links out of the checkout, such as the shared SPEC, are skipped); a `#fragment` must
   name a heading of the target page. A link in the book must stay
   inside docs/src, since nothing outside it is copied into the built book.
2. The built book (docs/book, from `mdbook build docs`), when it exists: every relative href/src of
   every HTML page must name a file of the build, and every fragment an id of that page.

Usage: python3 tools/docs/check_links.py [REPO_ROOT]. Prints one line per broken link
(`file:line: link: why`) and exits 1 if there is any.
"""

import html.parser
import pathlib
import re
import sys
import urllib.parse

LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
EXTERNAL = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def slug(heading: str) -> str:
    """The id mdBook gives a heading: lower case, markup and punctuation dropped, spaces to '-'."""
    text = re.sub(r"`([^`]*)`", r"\1", heading)
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"<[^>]+>", "", text)
    out = []
    for ch in text.strip().lower():
        if ch.isalnum() or ch in "-_":
            out.append(ch)
        elif ch.isspace():
            out.append("-")
    return "".join(out)


def markdown_lines(path: pathlib.Path):
    """(line number, text) of a Markdown file outside fenced code blocks, inline code removed."""
    fenced = False
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            yield number, re.sub(r"`+[^`]*`+", "", line)


def headings(path: pathlib.Path) -> set:
    """The fragment ids of a Markdown page's headings (repeats get -1, -2, ... as in mdBook)."""
    seen, ids = {}, set()
    for _, line in markdown_lines(path):
        match = HEADING.match(line)
        if match:
            base = slug(match.group(2))
            count = seen.get(base, 0)
            seen[base] = count + 1
            ids.add(base if count == 0 else f"{base}-{count}")
    return ids


def check_markdown(root: pathlib.Path, files, book_src: pathlib.Path):
    errors = []
    for path in files:
        in_book = book_src in path.parents
        for number, line in markdown_lines(path):
            for target in LINK.findall(line):
                if EXTERNAL.match(target):
                    continue
                where = f"{path.relative_to(root)}:{number}: {target}"
                file_part, _, fragment = target.partition("#")
                resolved = (path.parent / urllib.parse.unquote(file_part)).resolve() if file_part else path
                if root not in resolved.parents and resolved != root:
                    continue  # outside the checkout (the shared SPEC next to it): not ours to check
                if not resolved.exists():
                    errors.append(f"{where}: no such file {resolved.relative_to(root)}")
                    continue
                if in_book and book_src.resolve() not in resolved.parents and resolved != book_src.resolve():
                    errors.append(f"{where}: leaves docs/src, so the built book cannot serve it (name the file as code instead)")
                    continue
                if fragment and resolved.suffix == ".md" and fragment not in headings(resolved):
                    errors.append(f"{where}: no heading #{fragment} in {resolved.name}")
    return errors


class _Refs(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.refs, self.ids = [], set()

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if name == "id" and value:
                self.ids.add(value)
            if name in ("href", "src") and value is not None:
                self.refs.append((self.getpos()[0], value))


def parse_html(path: pathlib.Path) -> _Refs:
    parser = _Refs()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


def check_book(root: pathlib.Path, book: pathlib.Path):
    errors, pages = [], {}
    for page in sorted(book.rglob("*.html")):
        pages[page.resolve()] = parse_html(page)
    for page, parsed in pages.items():
        for number, ref in parsed.refs:
            if EXTERNAL.match(ref) or ref.startswith("/"):  # web links, and the site root of 404.html
                continue
            file_part, _, fragment = ref.partition("#")
            file_part = file_part.split("?")[0]
            target = (page.parent / urllib.parse.unquote(file_part)).resolve() if file_part else page
            where = f"{page.relative_to(root.resolve())}:{number}: {ref}"
            if target.is_dir():
                target = target / "index.html"
            if not target.exists():
                errors.append(f"{where}: no such file in the built book")
            elif fragment and target.suffix == ".html":
                ids = pages[target].ids if target in pages else parse_html(target).ids
                if urllib.parse.unquote(fragment) not in ids:
                    errors.append(f"{where}: no id #{fragment} on {target.name}")
    return errors


def main() -> int:
    root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
    book_src = root / "docs" / "src"
    files = [root / "README.md", *sorted(book_src.rglob("*.md"))]
    errors = check_markdown(root, files, book_src)
    book = root / "docs" / "book"
    checked_book = book.exists()
    if checked_book:
        errors += check_book(root, book)
    for error in errors:
        print(error)
    summary = f"{len(files)} Markdown files" + (", the built book" if checked_book else "")
    print(f"check_links: {summary}: {len(errors)} broken link(s)", file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
