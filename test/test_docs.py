"""The docs stay true to the code and findable: docs/design.md's parameter tables equal what the nodes
declare; every link, file path, module and citation key the README and docs/ cite exists; every page
of docs/ is listed in docs/index.md; the README stays an entry point (short: the results live in
docs/); no page and no source file tells the history of an issue (git has it)."""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path

import pytest
from repo_paths import REPO

ROOT = REPO
ROOT_THIS = Path(__file__).resolve()  # this file: its regex examples are history on purpose
DOCS = ROOT / "docs"
DESIGN = DOCS / "design.md"
REFERENCES = DOCS / "references.md"
README = ROOT / "README.md"
INDEX = DOCS / "index.md"
#: every Markdown page: the README and docs/*.md
PAGES = (README, *sorted(DOCS.glob("*.md")))
CHECKED = PAGES
#: the README is an entry point, not a lab notebook (docs/ holds the results)
README_MAX_LINES = 260
#: history in prose: "issue #17", "(#17)", "before this session", "session 5"
HISTORY_RE = re.compile(r"\b[Ii]ssue #?\d+|\(#\d+\)|\bbefore this (?:session|issue|step)\b|\b[Ss]ession \d+\b")

#: backtick spans that are repository paths / importable names of the workspace
PATH_RE = re.compile(r"^(?:src|test|tools|docs|bags|bench|\.ci)/[^\s<>*{}|]*$")
#: ... and paths inside a package, e.g. `dpos_ros/io/flow.py` for src/dpos_ros/dpos_ros/io/flow.py
PKG_PATH_RE = re.compile(r"^(dpos_core|dpos_ros)/[^\s<>*{}|:]+\.py$")
MODULE_RE = re.compile(r"^(?:dpos_core|dpos_ros|pos_master_node|pos_sub_node|ifa_node|transfer_align_node|sar_nav_node)(?:\.\w+)+$")
#: citation keys: [Gong2018], [vanderMerwe2000], [LSFit]
KEY_RE = re.compile(r"\[((?:[A-Z][A-Za-z]*|van[A-Za-z]+)\d{4}|LSFit)\]")
LINK_RE = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _param_tables():
    spec = importlib.util.spec_from_file_location("param_tables", ROOT / "tools" / "param_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _code_spans(text: str) -> list[str]:
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # fenced blocks are examples, not citations
    return re.findall(r"`([^`\n]+)`", text)


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading."""
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def _anchors(text: str) -> set[str]:
    return {_slug(m) for m in re.findall(r"^#+\s+(.*)$", text, flags=re.M)}


def test_parameter_tables_match_the_config_dataclasses():
    pt = _param_tables()
    problems = pt.stale(DESIGN)
    assert not problems, "docs/design.md parameter tables are stale; run .venv/bin/python tools/param_tables.py\n" + "\n".join(problems)


def test_every_node_has_a_table():
    pt = _param_tables()
    text = DESIGN.read_text(encoding="utf-8")
    for node, table in pt.tables().items():
        assert f"{pt._begin(node)}\n{table}\n{pt._end(node)}" in text
        config = pt.config_class(node)
        for name in config.__dataclass_fields__:
            assert f"| `{name}` |" in table


def _rel(path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("doc", CHECKED, ids=_rel)
def test_relative_links_exist(doc):
    text = doc.read_text(encoding="utf-8")
    bad = []
    for target in LINK_RE.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = doc if not path else (doc.parent / path).resolve()
        if not dest.exists():
            bad.append(f"{target}: {dest} does not exist")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest.read_text(encoding="utf-8")):
            bad.append(f"{target}: no heading #{anchor} in {dest.name}")
    assert not bad, "\n".join(bad)


def _path_exists(span: str) -> bool:
    """A repository path, or a pytest node id ``path::test_name[params]`` whose test is defined."""
    path, _, test = span.partition("::")
    pkg = PKG_PATH_RE.match(path)
    if pkg:
        path = f"src/{pkg.group(1)}/{path}"
    if not (ROOT / path).exists():
        return False
    name = test.split("::")[-1].partition("[")[0]
    return not name or re.search(rf"^\s*def {re.escape(name)}\(", (ROOT / path).read_text(encoding="utf-8"), flags=re.M) is not None


@pytest.mark.parametrize("doc", CHECKED, ids=_rel)
def test_cited_paths_exist(doc):
    spans = [s for s in _code_spans(doc.read_text(encoding="utf-8")) if PATH_RE.match(s) or PKG_PATH_RE.match(s)]
    if doc is DESIGN:
        assert spans  # the regex does find the design's paths
    missing = [s for s in spans if not _path_exists(s)]
    assert not missing, f"{doc.name} cites paths that do not exist: {missing}"


def _resolve(name: str) -> bool:
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


@pytest.mark.parametrize("doc", CHECKED, ids=_rel)
def test_cited_modules_exist(doc):
    names = sorted({s for s in _code_spans(doc.read_text(encoding="utf-8")) if MODULE_RE.match(s)})
    missing = [n for n in names if not _resolve(n)]
    assert not missing, f"{doc.name} cites modules / attributes that do not exist: {missing}"


def test_citation_keys_are_defined_in_references():
    defined = set(re.findall(r"^\| \[([^\]]+)\] \|", REFERENCES.read_text(encoding="utf-8"), flags=re.M))
    used: dict[str, set[str]] = {}
    sources = [*PAGES, *sorted((ROOT / "src").rglob("*.py"))]
    for path in sources:
        for key in KEY_RE.findall(path.read_text(encoding="utf-8")):
            used.setdefault(key, set()).add(str(path.relative_to(ROOT)))
    assert {"Gong2018", "Fang2012", "Ye2024", "Yan2016", "LSFit"} <= defined
    undefined = {k: sorted(v) for k, v in used.items() if k not in defined}
    assert not undefined, f"citation keys not in docs/references.md: {undefined}"


def test_method_lists_in_the_doc_are_the_code_lists():
    from dpos_core.ifa.pipeline import METHODS as IFA_METHODS
    from dpos_core.ta.pipeline import METHODS as TA_METHODS

    text = " ".join(DESIGN.read_text(encoding="utf-8").split())
    assert "`dpos_core.ta.pipeline.METHODS` = " + ", ".join(f"`{m}`" for m in TA_METHODS) in text
    assert "`dpos_core.ifa.pipeline.METHODS` = " + ", ".join(f"`{m}`" for m in IFA_METHODS) in text


def test_every_page_of_docs_is_in_the_index():
    """docs/index.md links every page of docs/ (and nothing that is not there: the link test)."""
    linked = {(INDEX.parent / target.partition("#")[0]).resolve() for target in LINK_RE.findall(INDEX.read_text(encoding="utf-8"))}
    pages = {p.resolve() for p in DOCS.glob("*.md") if p != INDEX}
    assert pages, "no pages found in docs/"
    missing = sorted(p.name for p in pages - linked)
    assert not missing, f"docs/index.md does not list: {missing}"
    assert INDEX.resolve() in {(README.parent / t.partition("#")[0]).resolve() for t in LINK_RE.findall(README.read_text(encoding="utf-8"))}, \
        "the README does not point at docs/index.md"


def test_every_figure_is_used():
    used = " ".join(p.read_text(encoding="utf-8") for p in PAGES)
    unused = sorted(f.name for f in (DOCS / "img").iterdir() if f.name not in used)
    assert not unused, f"figures in docs/img/ that no page shows: {unused}"


def test_readme_is_an_entry_point():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES}): move the details to docs/"
    text = "\n".join(lines)
    for command in ("make demo", "make test", "dpos-graph", "dpos-play", "dpos-process", "dpos-import", "dpos-ifa"):
        assert command in text, f"README.md does not show {command}"


def _history(path) -> list[str]:
    return [f"{_rel(path)}:{i}: {line.strip()}" for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if HISTORY_RE.search(line)]


def test_history_regex():
    for s in ("issue #17", "(issue #15 item 3)", "Issue #11's goal", "fixed in (#4)", "before this session", "session 5"):
        assert HISTORY_RE.search(s), s
    for s in ("this session's products", "the session ends", "/session/end", "#15 of the list", "issue a warning"):
        assert not HISTORY_RE.search(s), s


def test_no_history_in_the_docs():
    found = [hit for page in PAGES for hit in _history(page)]
    assert not found, "history in the docs (git has it; state the current behaviour):\n" + "\n".join(found)




def test_no_history_in_the_sources():
    sources = [p for top in ("src", "test", "bench", "tools") for p in sorted((ROOT / top).rglob("*"))
               if p.suffix in (".py", ".yaml", ".xml", ".cfg") and p.is_file() and p.resolve() != ROOT_THIS
               and "__pycache__" not in p.parts]
    hits: dict[str, list[str]] = {}
    for path in sources:
        found = _history(path)
        if found:
            hits[_rel(path)] = found
    assert not hits, "history in docstrings or comments (state the current behaviour):\n" + "\n".join(h for v in hits.values() for h in v)
