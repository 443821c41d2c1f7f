"""The documentation holds together (docs/development.md, "Documentation"): every relative link and
image in README.md and docs/*.md resolves (anchors too), the README stays short and starts with the
two commands, and every page in docs/ is listed in docs/index.md and in mkdocs.yml's nav. Fast, no
network, no MkDocs needed; each checker is also run on a broken input, so each check can fail."""

import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
INDEX = DOCS / "index.md"
MKDOCS = ROOT / "mkdocs.yml"

RUN_COMMAND = (
    "python3 -m venv .venv && .venv/bin/pip install -e '.[standalone]' && .venv/bin/haptic-teleop run wall_contact"
)
TEST_COMMAND = (
    "python3 -m venv .venv && .venv/bin/pip install -e '.[standalone,test]' "
    "&& .venv/bin/python -m pytest -q -p no:cacheprovider -n 2"
)
README_MAX_LINES = 200

FENCE = re.compile(r"^(```|~~~).*?^\1[ \t]*$", re.M | re.S)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[(?:[^\]\\]|\\.)*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^(#{1,6})[ \t]+(.+?)[ \t]*#*[ \t]*$", re.M)
EXTERNAL = re.compile(r"^[a-z][a-z0-9+.-]*:", re.I)  # http:, https:, mailto:, ...


def pages() -> list[Path]:
    return sorted(DOCS.glob("*.md"))


def prose(text: str) -> str:
    """The text without fenced code blocks and inline code spans (links there are not links)."""
    return INLINE_CODE.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """A heading's anchor as GitHub and MkDocs make it: the text without Markdown markup,
    lowercase, punctuation removed, each space a hyphen."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link: its text
    text = re.sub(r"[`*]", "", text).strip().lower()
    text = re.sub(r"[^\w\s-]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {slug(m.group(2)) for m in HEADING.finditer(FENCE.sub("", path.read_text()))}


def links(path: Path) -> list[str]:
    return [m.group(1) for m in LINK.finditer(prose(path.read_text()))]


def broken_links(path: Path, inside: Path = ROOT) -> list[str]:
    """Every relative link or image of `path` that does not resolve: a missing file, a file
    outside `inside`, an absolute path, or an anchor that is no heading of its page."""
    bad = []
    for target in links(path):
        if EXTERNAL.match(target):
            continue
        where, _, anchor = target.partition("#")
        if where.startswith("/"):
            bad.append(f"{path.name}: {target}: an absolute path")
            continue
        dest = (path.parent / where).resolve() if where else path.resolve()
        if not dest.is_relative_to(inside.resolve()):
            bad.append(f"{path.name}: {target}: outside {inside.name}/")
        elif not dest.is_file():
            bad.append(f"{path.name}: {target}: no such file")
        elif anchor and (dest.suffix != ".md" or anchor not in anchors(dest)):
            bad.append(f"{path.name}: {target}: no heading with anchor #{anchor} in {dest.name}")
    return bad


def readme_problems(text: str, ci_run: str) -> list[str]:
    """The README is under README_MAX_LINES lines and its first two code blocks, before any
    section, are the run command and the test command; .ci/run runs the same test command (with
    pip's -q)."""
    bad = []
    n = len(text.splitlines())
    if n >= README_MAX_LINES:
        bad.append(f"README.md has {n} lines; keep it under {README_MAX_LINES}")
    head = text.split("\n## ", 1)[0]
    blocks = [b.strip() for b in re.findall(r"^```bash\n(.*?)^```", head, re.M | re.S)]
    if blocks[:2] != [RUN_COMMAND, TEST_COMMAND]:
        bad.append(f"README.md does not start with the run and the test command: {blocks[:2]}")
    m = re.search(r"^# README test command:\n(.+)$", ci_run, re.M)
    if m is None or m.group(1).replace(" install -q ", " install ") != TEST_COMMAND:
        bad.append(f".ci/run's README test command is not the README's: {m.group(1) if m else None!r}")
    return bad


def nav_files(nav: object) -> list[str]:
    """Every page a mkdocs nav names, in order."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [f for item in nav for f in nav_files(item)]
    if isinstance(nav, dict):
        return [f for value in nav.values() for f in nav_files(value)]
    return []


def unlisted_pages(names: list[str], index_text: str, nav: object) -> list[str]:
    listed = set(LINK.findall(prose(index_text)))
    in_nav = nav_files(nav)
    bad = [f"{n}: not linked from docs/index.md" for n in names if n != "index.md" and n not in listed]
    bad += [f"{n}: not in mkdocs.yml's nav" for n in names if n not in in_nav]
    bad += [f"{n}: in mkdocs.yml's nav but not in docs/" for n in in_nav if n not in names]
    return bad


def index_groups(index_text: str) -> list[str]:
    """The section titles of docs/index.md that list pages (the papers' section lists none)."""
    sections = re.split(r"^## ", FENCE.sub("", index_text), flags=re.M)[1:]
    return [s.splitlines()[0].strip() for s in sections if "| page |" in s]


def exit_code_table(text: str) -> str:
    m = re.search(r"^\| code \| when \|\n(?:\|.*\n?)+", text, re.M)
    assert m is not None, "no exit-code table"
    return m.group(0).strip()


def mkdocs_config() -> dict:
    return yaml.safe_load(MKDOCS.read_text())


# -- the repository's documentation ------------------------------------------------------------


@pytest.mark.parametrize("path", [README, *pages()], ids=lambda p: p.name)
def test_every_relative_link_and_image_resolves(path):
    # docs/ is built by MkDocs, which accepts no link out of docs/ in strict mode
    inside = DOCS if path.parent == DOCS else ROOT
    assert broken_links(path, inside) == []


def test_the_readme_is_short_and_starts_with_the_two_commands():
    assert readme_problems(README.read_text(), (ROOT / ".ci" / "run").read_text()) == []


def test_every_page_is_in_the_index_and_the_nav():
    names = [p.name for p in pages()]
    assert unlisted_pages(names, INDEX.read_text(), mkdocs_config()["nav"]) == []


def test_the_nav_follows_the_index_groups():
    config = mkdocs_config()
    assert config["docs_dir"] == "docs"
    groups = [
        title for item in config["nav"] if isinstance(item, dict) for title, v in item.items() if isinstance(v, list)
    ]
    assert groups == index_groups(INDEX.read_text())


def test_the_readme_and_docs_outputs_md_have_the_same_exit_codes():
    assert exit_code_table(README.read_text()) == exit_code_table((DOCS / "outputs.md").read_text())


# -- each check fails on a broken input --------------------------------------------------------


def test_the_link_check_finds_a_missing_file_a_missing_anchor_and_a_link_out(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "b.md").write_text("# Title\n\n## A section (`code`), too\n")
    page = tmp_path / "docs" / "a.md"
    page.write_text(
        "[ok](b.md) [ok](b.md#a-section-code-too) ![ok](b.md) [ok](#here) [web](https://example.com)\n"
        "`[not a link](nowhere.md)`\n\n```\n[not a link](nowhere.md)\n```\n\n## Here\n"
    )
    assert broken_links(page, tmp_path / "docs") == []
    page.write_text("[gone](c.md) [bad](b.md#no-such) ![img](x.png) [out](../README.md) [abs](/etc/passwd)\n")
    (tmp_path / "README.md").write_text("# R\n")
    bad = broken_links(page, tmp_path / "docs")
    assert len(bad) == 5, bad


def test_the_readme_check_finds_a_long_readme_and_a_changed_command():
    ci = f"# README test command:\n{TEST_COMMAND.replace(' install ', ' install -q ')}\n"
    good = f"# t\n\n```bash\n{RUN_COMMAND}\n```\n\n```bash\n{TEST_COMMAND}\n```\n\n## More\n"
    assert readme_problems(good, ci) == []
    assert len(readme_problems(good + "x\n" * README_MAX_LINES, ci)) == 1
    assert len(readme_problems(good.replace("wall_contact", "stiff_wall"), ci)) == 1
    assert len(readme_problems(good, ci.replace("pytest -q", "pytest"))) == 1


def test_the_listing_check_finds_a_page_missing_from_the_index_or_the_nav():
    index = "[a](a.md) [b](b.md)"
    nav = [{"Home": "index.md"}, {"Group": ["a.md", "b.md"]}]
    assert unlisted_pages(["a.md", "b.md", "index.md"], index, nav) == []
    assert len(unlisted_pages(["a.md", "b.md", "c.md", "index.md"], index, nav)) == 2
    assert len(unlisted_pages(["a.md", "index.md"], "[a](a.md)", nav)) == 1
