"""tools/house_metrics.py counts what it says on a small tree made here (twins, long parameter
lists, circles, upward arrows, in-function imports, exception classes outside the hierarchy)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from repo_paths import REPO

_spec = importlib.util.spec_from_file_location("house_metrics", REPO / "tools" / "house_metrics.py")
assert _spec is not None and _spec.loader is not None
house_metrics = importlib.util.module_from_spec(_spec)
sys.modules["house_metrics"] = house_metrics
_spec.loader.exec_module(house_metrics)


def _tree(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / "src" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    (root / "README.md").write_text("a\nb\nc\n")
    return root


def test_counts_on_a_made_tree(tmp_path: Path) -> None:
    params = ", ".join(f"a{i}" for i in range(10))
    repo = _tree(tmp_path, {
        "dpos_core/dpos_core/__init__.py": "",
        "dpos_core/dpos_core/errors.py": "class DposError(Exception):\n    pass\n",
        "dpos_core/dpos_core/a.py": (
            "from dpos_core import b\n\n"
            f"def many(self, {params}):\n    return 0\n\n"
            "def solve():\n    import numpy\n    from dpos_core import b\n    return b\n\n"
            "def solve_streaming():\n    return 1\n\n"
            "class Oops(ValueError):\n    pass\n\n"
            "class AntennaSolution:\n    pass\n\n"
            "class StreamedAntenna:\n    pass\n"),
        "dpos_core/dpos_core/b.py": "from . import a\n",
        "dpos_ros/dpos_ros/__init__.py": "",
        "dpos_ros/dpos_ros/c.py": "import ifa_node.params\n",
        "ifa_node/ifa_node/__init__.py": "",
        "ifa_node/ifa_node/params.py": "X = 1\n",
    })
    m = house_metrics.measure(repo)
    assert m["twin_functions"] == ["AntennaSolution / StreamedAntenna", "solve / solve_streaming"]
    assert [x.split(" ")[0] for x in m["functions_10plus_params"]] == ["dpos_core.a.many"]  # self not counted: 10 left
    assert m["import_circles"] == [["dpos_core.a", "dpos_core.b"]]
    assert m["upward_arrows"] == ["dpos_ros.c imports ifa_node.params"]
    assert m["in_function_imports_all"] == 2
    assert len(m["in_function_imports_own"]) == 1 and m["in_function_imports_own"][0].endswith("dpos_core")
    assert m["exception_classes_outside_errors"] == ["dpos_core.a.Oops"]
    assert m["readme_lines"] == 3
    assert m["longest_file"][0] == "src/dpos_core/dpos_core/a.py"


def test_a_clean_tree_counts_nothing(tmp_path: Path) -> None:
    repo = _tree(tmp_path, {"dpos_core/dpos_core/__init__.py": "", "dpos_core/dpos_core/a.py": "import math\n\ndef f(x):\n    return math.sin(x)\n"})
    m = house_metrics.measure(repo)
    assert not (m["twin_functions"] or m["functions_10plus_params"] or m["import_circles"] or m["upward_arrows"]
                or m["in_function_imports_own"] or m["exception_classes_outside_errors"])
    assert m["in_function_imports_all"] == 0
