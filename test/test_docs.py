"""docs/design.md stays true to the code: the parameter tables equal what the nodes declare, and
every link, file path, module and citation key it (and docs/references.md) cites exists."""

from __future__ import annotations

import importlib
import importlib.util
import re

import pytest
from repo_paths import REPO

ROOT = REPO
DOCS = ROOT / "docs"
DESIGN = DOCS / "design.md"
REFERENCES = DOCS / "references.md"
CHECKED = (DESIGN, REFERENCES)

#: backtick spans that are repository paths / importable names of the workspace
PATH_RE = re.compile(r"^(?:src|test|tools|docs|bags|bench|\.ci)/[^\s<>*{}|]*$")
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


@pytest.mark.parametrize("doc", CHECKED, ids=lambda p: p.name)
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


@pytest.mark.parametrize("doc", CHECKED, ids=lambda p: p.name)
def test_cited_paths_exist(doc):
    spans = [s for s in _code_spans(doc.read_text(encoding="utf-8")) if PATH_RE.match(s)]
    assert spans or doc is REFERENCES  # the regex does find the design's paths
    missing = [s for s in spans if not (ROOT / s).exists()]
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


@pytest.mark.parametrize("doc", CHECKED, ids=lambda p: p.name)
def test_cited_modules_exist(doc):
    names = sorted({s for s in _code_spans(doc.read_text(encoding="utf-8")) if MODULE_RE.match(s)})
    missing = [n for n in names if not _resolve(n)]
    assert not missing, f"{doc.name} cites modules / attributes that do not exist: {missing}"


def test_citation_keys_are_defined_in_references():
    defined = set(re.findall(r"^\| \[([^\]]+)\] \|", REFERENCES.read_text(encoding="utf-8"), flags=re.M))
    used: dict[str, set[str]] = {}
    sources = [DESIGN, ROOT / "README.md", *sorted((ROOT / "src").rglob("*.py"))]
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
