"""The documentation as a reader gets it (docs/development.md, "Documentation"): MkDocs builds the site
with --strict, every page of mkdocs.yml's nav is an HTML page with a title and content, and every link,
anchor, script, stylesheet and image in every built page resolves inside the site (images are real
PNG/SVG/JPEG files). Headless Chromium is not installed here nor on CI (no browser binary, none can be
downloaded), so the checks read the built HTML with the standard library's html.parser instead. Each
checker is also run on a small broken site built here, so each check can fail."""

import functools
import re
import subprocess
import sys
from collections.abc import Iterator
from html.parser import HTMLParser
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

import pytest
import yaml

pytest.importorskip("mkdocs")

ROOT = Path(__file__).resolve().parents[1]
EXTERNAL = re.compile(r"^([a-z][a-z0-9+.-]*:|//)", re.I)  # http:, https:, mailto:, protocol-relative
LINKING = {"a": "href", "link": "href", "script": "src", "img": "src"}
RASTER = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff")  # PNG, JPEG


class Page(HTMLParser):
    """One built page: its <title>, the text of the theme's content container (the default theme's
    <div class="col-md-9" role="main">), every element id, and every (tag, URL) it links to."""

    def __init__(self, html: str) -> None:
        super().__init__(convert_charrefs=True)
        self.title = ""
        self.main = ""
        self.ids: set[str] = set()
        self.links: list[tuple[str, str]] = []
        self._in_title = False
        self._main_divs = 0  # how deep inside the content container, counted in <div>s
        self.feed(html)
        self.close()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        attr = dict(attrs)
        if attr.get("id"):
            self.ids.add(str(attr["id"]))
        if tag in LINKING and attr.get(LINKING[tag]) is not None:
            self.links.append((tag, str(attr[LINKING[tag]])))
        self._in_title = self._in_title or tag == "title"
        if tag == "div" and (self._main_divs or attr.get("role") == "main"):
            self._main_divs += 1

    def handle_endtag(self, tag: str) -> None:
        self._in_title = self._in_title and tag != "title"
        if tag == "div" and self._main_divs:
            self._main_divs -= 1

    def handle_data(self, data: str) -> None:
        self.title += data if self._in_title else ""
        self.main += data if self._main_divs else ""


@functools.cache
def parse(path: Path) -> Page:
    return Page(path.read_text(encoding="utf-8"))


def build(config: Path, site: Path, strict: bool = True) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "mkdocs", "build", "-f", str(config), "-d", str(site)]
    return subprocess.run([*command, "--strict"] if strict else command, capture_output=True, text=True, timeout=300)


def nav_pages(config: Path) -> list[str]:
    """The nav's pages as built files (use_directory_urls: false, so x.md is x.html)."""

    def walk(item: Any) -> Iterator[str]:
        if isinstance(item, str):
            yield item
        for child in item.values() if isinstance(item, dict) else item if isinstance(item, list) else []:
            yield from walk(child)

    nav = yaml.safe_load(config.read_text())["nav"]
    return [re.sub(r"\.md$", ".html", page) for page in walk(nav) if not EXTERNAL.match(page)]


def page_problems(site: Path, page: str) -> list[str]:
    if not (site / page).is_file():
        return [f"{page}: not in the site"]
    built = parse(site / page)
    return [f"{page}: empty <title>"] * (not built.title.strip()) + [f"{page}: no main content"] * (
        not built.main.strip()
    )


def is_image(path: Path) -> bool:
    head = path.read_bytes()[:4096]
    svg = head.lstrip().startswith((b"<svg", b"<?xml", b"<!--")) and b"<svg" in head
    return head.startswith(RASTER) or svg


def link_problems(site: Path) -> list[str]:
    """Every relative (or site-absolute) URL in every built page: a file in the site, a #fragment an id in
    that page, an <img> a real image. The theme's own css/, js/, search/ and img/ files are checked too."""
    problems = []
    for page in sorted(site.rglob("*.html")):
        for tag, url in parse(page).links:
            if EXTERNAL.match(url):
                continue
            parts = urlsplit(url)
            path = unquote(parts.path)
            target = (
                (site / path.lstrip("/") if path.startswith("/") else page.parent / path).resolve() if path else page
            )
            where = f"{page.relative_to(site)}: <{tag}> {url}"
            if not target.is_relative_to(site) or not target.is_file():
                problems.append(f"{where}: no such file in the site")
                continue
            fragment = unquote(parts.fragment)
            if fragment and (target.suffix != ".html" or fragment not in parse(target).ids):
                problems.append(f"{where}: no element with id {fragment!r}")
            if tag == "img" and not is_image(target):
                problems.append(f"{where}: not a PNG/SVG/JPEG image")
    return problems


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("docs_site") / "site"
    result = build(ROOT / "mkdocs.yml", out)
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stderr}"
    return out.resolve()


def test_every_nav_page_is_built_with_title_and_content(site: Path) -> None:
    pages = nav_pages(ROOT / "mkdocs.yml")
    assert "index.html" in pages
    problems = [problem for page in pages for problem in page_problems(site, page)]
    assert not problems, "\n".join(problems)


def test_every_link_anchor_and_image_resolves(site: Path) -> None:
    problems = link_problems(site)
    assert not problems, "\n".join(problems)


def test_the_checkers_catch_a_broken_site(tmp_path: Path) -> None:
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text(
        "# Home\n\n[gone](missing.md), [anchor](other.md#nowhere), [fine](other.md#other)\n\n"
        "![missing](missing.png) ![fake](fake.png)\n"
    )
    (docs / "other.md").write_text("# Other\n\nText.\n")
    (docs / "fake.png").write_text("not an image\n")
    config = tmp_path / "mkdocs.yml"
    config.write_text(
        "site_name: broken\ndocs_dir: docs\nuse_directory_urls: false\nnav: [index.md, other.md, absent.md]\n"
    )
    result = build(config, tmp_path / "site", strict=False)  # --strict would refuse this site
    assert result.returncode == 0, result.stderr
    site = (tmp_path / "site").resolve()
    (site / "blank.html").write_text("<html><head><title> </title></head><body><p>no container</p></body></html>")

    pages = [problem for page in [*nav_pages(config), "blank.html"] for problem in page_problems(site, page)]
    assert pages == ["absent.html: not in the site", "blank.html: empty <title>", "blank.html: no main content"]
    assert link_problems(site) == [  # the nav's link to the absent page is broken on every page too
        "404.html: <a> /absent.md: no such file in the site",
        "index.html: <a> absent.md: no such file in the site",
        "index.html: <a> missing.md: no such file in the site",
        "index.html: <a> other.html#nowhere: no element with id 'nowhere'",
        "index.html: <img> missing.png: no such file in the site",
        "index.html: <img> fake.png: not a PNG/SVG/JPEG image",
        "other.html: <a> absent.md: no such file in the site",
    ]
