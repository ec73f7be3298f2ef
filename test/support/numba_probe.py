"""What numba compiles in a fresh interpreter (the warm-up tests: after a warm-up, real use must
compile no kernel that the warm-up did not).

:func:`new_after_warm_up` runs ``script`` in a new Python process (nothing compiled or loaded
there yet) with :data:`PRELUDE` before it; the script calls ``mark("warm_up")`` after its
warm-up and ``mark("use")`` after the real use (``mark("data")`` may set aside what preparing
the data compiled).  Returns the kernels (``module.name``) that gained a signature after the
warm-up's mark, and how many had one at it."""

from __future__ import annotations

import json
import subprocess
import sys

PRELUDE = r'''
import json, sys
from numba.core.registry import CPUDispatcher

_MARKS = {}

def _compiled():
    out = {}
    for name, mod in list(sys.modules.items()):
        for attr, d in (list(vars(mod).items()) if mod is not None else []):
            if isinstance(d, CPUDispatcher):
                out[f"{name}.{attr}"] = sorted(str(s) for s in d.signatures)
    return out

def mark(what):
    _MARKS[what] = _compiled()
    if what == "use":
        print("NUMBA_PROBE " + json.dumps(_MARKS))
'''


def new_after_warm_up(script: str, *args: str, timeout_s: float = 600.0) -> tuple[dict[str, list[str]], int]:
    r = subprocess.run([sys.executable, "-c", PRELUDE + script, *args], capture_output=True, text=True, timeout=timeout_s)
    assert r.returncode == 0, r.stderr[-3000:]
    (line,) = [x for x in r.stdout.splitlines() if x.startswith("NUMBA_PROBE ")]
    marks = json.loads(line.removeprefix("NUMBA_PROBE "))
    before = {k: set(v) for m in ("warm_up", "data") for k, v in marks.get(m, {}).items()}
    base: dict[str, set[str]] = {}
    for k, v in before.items():
        base.setdefault(k, set()).update(v)
    new = {k: sorted(set(v) - base.get(k, set())) for k, v in marks["use"].items()}
    return {k: v for k, v in new.items() if v}, sum(1 for v in marks["warm_up"].values() if v)
