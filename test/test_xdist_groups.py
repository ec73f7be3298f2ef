"""make test's ``-n 2 --dist loadgroup`` really keeps a module's tests that share a module fixture on
one worker (pytest-xdist 3.8 groups by setting ``item._nodeid``, which pytest 9.2 ignores: then each
worker silently built the fixture again); tests without such a fixture are still dealt to both; the long tests are dealt first."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from xdist_groups import heavy_first  # test/support/xdist_groups.py

SUPPORT = Path(__file__).parent / "support"

CONFTEST = """
from pathlib import Path
import pytest
from xdist_groups import group_module_fixture_tests

@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    group_module_fixture_tests(items, Path(__file__).parent)
"""

SHARED = """
import os, pytest
from pathlib import Path

@pytest.fixture(scope="module")
def built():
    with open(Path(__file__).parent / "builds.txt", "a") as f:
        f.write(os.environ["PYTEST_XDIST_WORKER"] + "\\n")
    return 1

""" + "".join(f"def test_shared_{k}(built):\n    assert built == 1\n\n" for k in range(8))

FREE = """
import os, time
from pathlib import Path

""" + "".join(f"def test_free_{k}():\n    time.sleep(0.2)\n    with open(Path(__file__).parent / 'free.txt', 'a') as f:\n"
              f"        f.write(os.environ['PYTEST_XDIST_WORKER'] + '\\n')\n\n" for k in range(8))


def test_a_module_fixture_is_built_once_on_two_workers(tmp_path: Path) -> None:
    (tmp_path / "conftest.py").write_text(CONFTEST)
    (tmp_path / "test_shared.py").write_text(SHARED)
    (tmp_path / "test_free.py").write_text(FREE)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SUPPORT), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2", "--dist", "loadgroup",
                        "-c", os.devnull, "--rootdir", str(tmp_path), str(tmp_path)],
                       capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "16 passed" in r.stdout, r.stdout
    assert len((tmp_path / "builds.txt").read_text().split()) == 1  # the module fixture: once, on one worker
    assert len(set((tmp_path / "free.txt").read_text().split())) == 2  # the others on both workers


class _Item:
    """A collected test as heavy_first sees it: its markers."""

    def __init__(self, name: str, *markers: str) -> None:
        self.name, self.markers = name, markers

    def get_closest_marker(self, name: str) -> str | None:
        return name if name in self.markers else None


def test_heavy_tests_are_dealt_first_in_their_order() -> None:
    items = [_Item("a"), _Item("b", "ros"), _Item("c"), _Item("d", "slow"), _Item("e", "xdist_group"), _Item("f", "parametrize")]
    heavy_first(items)  # type: ignore[arg-type]
    assert [i.name for i in items] == ["b", "d", "e", "a", "c", "f"]
