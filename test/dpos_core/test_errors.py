"""Errors that say what went wrong (issue "the house", item 5): the core's error hierarchy
(dpos_core.errors), rejected GNSS fixes vs programming errors, counted Cholesky repairs, and the
in-flight aligner's bank of heading hypotheses dropping a failing one with an event."""

from __future__ import annotations

import ast
import builtins
import pickle
import threading
import warnings
from dataclasses import replace

import numpy as np
import pytest
from repo_paths import REPO

from dpos_core import errors
from dpos_core.config import ConfigError, load_aircraft
from dpos_core.errors import DposError, NumericalFailure, NumericalRepairWarning, ParameterError, RejectedInput, TaskFailed
from dpos_core.filters import linalg
from dpos_core.filters.linalg import JitterRepairs, chol, solve_spd, total_jitter_repairs
from dpos_core.ifa.mechanization import initial_state_from_truth
from dpos_core.ifa.model import GnssFix, IfaFilterConfig, check_fix
from dpos_core.ifa.pipeline import InFlightAligner, run
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession

# ----------------------------------------------------------------------------- hierarchy


def test_hierarchy() -> None:
    assert issubclass(RejectedInput, DposError) and issubclass(RejectedInput, ValueError)
    assert issubclass(NumericalFailure, DposError) and issubclass(NumericalFailure, ArithmeticError)
    assert not issubclass(NumericalFailure, ValueError)  # a diverged filter is not a bad input
    assert issubclass(ConfigError, DposError) and issubclass(ConfigError, ValueError)
    with pytest.raises(DposError, match="unknown aircraft"):
        load_aircraft("no_such_aircraft")


def _exception_classes_in_src() -> dict[str, list[str]]:
    """Every exception class (not a warning) defined in src: class name -> the files defining it.

    Read from the sources: a class is an exception when one of its bases is a builtin exception
    or an exception class of src (by name), so that no module has to be imported."""
    defs: dict[str, tuple[list[str], list[str]]] = {}  # name -> (base names, files)
    for path in sorted((REPO / "src").glob("*/*/**/*.py")):
        if "build" in path.parts:
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ClassDef):
                bases = [b.id if isinstance(b, ast.Name) else b.attr for b in node.bases if isinstance(b, ast.Name | ast.Attribute)]
                defs.setdefault(node.name, ([], []))[0].extend(bases)
                defs[node.name][1].append(str(path.relative_to(REPO)))

    def builtin_kind(name: str) -> type | None:
        obj = getattr(builtins, name, None)
        return obj if isinstance(obj, type) and issubclass(obj, BaseException) else None

    exc: dict[str, bool] = {}  # name -> is a warning
    changed = True
    while changed:
        changed = False
        for name, (bases, _) in defs.items():
            if name in exc:
                continue
            kinds = [builtin_kind(b) for b in bases]
            if any(k is not None for k in kinds) or any(b in exc for b in bases):
                exc[name] = any(k is not None and issubclass(k, Warning) for k in kinds) or any(exc.get(b, False) for b in bases)
                changed = True
    return {name: defs[name][1] for name, warning in exc.items() if not warning}


def test_every_exception_class_of_the_workspace_is_in_the_hierarchy() -> None:
    found = _exception_classes_in_src()
    assert {"DposError", "ParameterError", "BagError", "ProductsExistError", "TaskFailed"} <= set(found)  # the scan sees them
    outside = {name: files for name, files in found.items() if files != ["src/dpos_core/dpos_core/errors.py"]}
    assert not outside, f"exception classes defined outside dpos_core/errors.py: {outside}"
    for name in found:
        assert issubclass(getattr(errors, name), DposError), name
        assert name in errors.__all__, name


@pytest.mark.parametrize(("name", "builtin"), [("ConfigError", ValueError), ("ParameterError", ValueError), ("InputError", ValueError),
                                               ("SarInputError", ValueError), ("SessionError", ValueError),
                                               ("LogFormatError", ValueError), ("ProductsExistError", FileExistsError),
                                               ("GraphError", RuntimeError)])
def test_errors_keep_their_builtin_base(name: str, builtin: type[Exception]) -> None:
    """``except ValueError`` (FileExistsError, RuntimeError) written before the hierarchy still catches them."""
    assert issubclass(getattr(errors, name), builtin)


def test_errors_with_arguments_survive_pickling() -> None:
    p = pickle.loads(pickle.dumps(ParameterError("rate_hz", -1, "must be > 0")))
    assert (str(p), p.name, p.value, p.reason) == ("invalid parameter 'rate_hz' = -1: must be > 0", "rate_hz", -1, "must be > 0")
    t = pickle.loads(pickle.dumps(TaskFailed("no /master/nav", 2)))
    assert (str(t), t.attempt) == ("no /master/nav", 2)


def test_errors_carry_what_went_wrong_through_pickling() -> None:
    """The transfer-alignment smoothers run in worker processes: the attributes survive."""
    e = pickle.loads(pickle.dumps(RejectedInput("bad fix", what="GNSS fix", reason="nan", t_s=3.0)))
    assert (str(e), e.what, e.reason, e.t_s) == ("bad fix", "GNSS fix", "nan", 3.0)
    f = pickle.loads(pickle.dumps(NumericalFailure("diverged", what="particle filter", t_s=7.5)))
    assert (str(f), f.what, f.t_s) == ("diverged", "particle filter", 7.5)


# ----------------------------------------------------------------------------- GNSS fix checks


def _fix(**kw) -> GnssFix:
    f = GnssFix(10.0, np.array([0.7, 2.0, 500.0]), np.ones(3), np.array([1.0, 2.0, 0.0]), np.full(3, 0.1))
    return replace(f, **kw)


@pytest.mark.parametrize(("fix", "last", "reason"), [
    (_fix(t_s=float("nan")), None, "nan"),
    (_fix(), 10.0, "duplicate"),
    (_fix(), 11.0, "out_of_order"),
    (_fix(llh=np.array([np.nan, 2.0, 500.0])), None, "nan"),
    (_fix(pos_sigma_m=np.zeros(3)), None, "zero_cov"),
    (_fix(llh=np.array([2.0, 2.0, 500.0])), None, "out_of_range"),
])
def test_check_fix_rejects_bad_data_with_a_reason(fix: GnssFix, last: float | None, reason: str) -> None:
    with pytest.raises(RejectedInput) as ei:
        check_fix(fix, last)
    assert ei.value.what == "GNSS fix" and ei.value.reason == reason


def test_a_wrong_shape_is_a_bug_not_a_rejected_fix() -> None:
    with pytest.raises(ValueError, match="shape") as ei:
        check_fix(_fix(llh=np.zeros(4)), None)
    assert not isinstance(ei.value, DposError)


# ----------------------------------------------------------------------------- chol repairs


def _factor(P: np.ndarray) -> np.ndarray:
    return chol(P)  # one call site


def test_chol_jitter_is_counted_and_warned_once_per_call_site() -> None:
    linalg.reset_repair_warnings()
    P = np.diag([4.0, 0.0, 1.0])  # PSD, singular: the plain factorization fails
    total0 = total_jitter_repairs()
    outer = JitterRepairs()
    with outer:
        with pytest.warns(NumericalRepairWarning, match=r"relative diagonal jitter of 1e-12 \(absolute 4e-12\)") as w:
            L = _factor(P)
        assert len(w) == 1 and w[0].filename == __file__  # attributed to the caller, not to linalg.py
        np.testing.assert_allclose(L @ L.T, P + 4e-12 * np.eye(3), rtol=0, atol=1e-15)
        inner = JitterRepairs()
        with inner, warnings.catch_warnings():
            warnings.simplefilter("error")  # the same call site again: counted, not warned
            for _ in range(3):
                _factor(P)
        assert inner.count == 3 and inner.max_relative == 1e-12 and inner.max_absolute == pytest.approx(4e-12)
    assert outer.count == 4 and total_jitter_repairs() - total0 == 4
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _factor(P)  # no counter active: only the process total
    assert outer.count == 4 and total_jitter_repairs() - total0 == 5
    # another call site (through solve_spd) is warned once too
    with pytest.warns(NumericalRepairWarning):
        solve_spd(P, np.ones((3, 1)))


def test_chol_counters_are_per_thread() -> None:
    mine = JitterRepairs()
    P = np.diag([1.0, 0.0])

    def other() -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            chol(P)

    with mine:
        t = threading.Thread(target=other)
        t.start()
        t.join()
    assert mine.count == 0


def test_chol_beyond_repair_is_a_numerical_failure() -> None:
    with pytest.raises(NumericalFailure, match=r"not positive definite.*smallest eigenvalue -1") as ei:
        chol(np.diag([1.0, -1.0, 1.0]))
    assert ei.value.what == "covariance"
    with pytest.raises(NumericalFailure, match="non-finite"):
        chol(np.diag([1.0, np.nan]))


# ----------------------------------------------------------------------------- the bank of hypotheses


@pytest.fixture(scope="module")
def short_ifa():
    ss = SimulatedSession(load_scenario("paper_ifa"), 5, duration_s=8.0)
    tr = ss.truth("master", np.array([0.0]))
    init = initial_state_from_truth(tr.q_nb[0], tr.vel_n_mps[0], tr.llh[0], 0.0, 30.0)
    return ss, ss.master_imu(), ss.gnss(), init


def _epochs(al: InFlightAligner, imu, g, js):
    recs = []
    for j in js:
        i0 = int(np.searchsorted(imu.t_s, al.model.t_s + 1e-9))
        i1 = int(np.searchsorted(imu.t_s, g.t_s[j] + 1e-6))
        al.propagate(imu.t_s[i0:i1], imu.omega_radps[i0:i1], imu.f_mps2[i0:i1])
        recs.append(al.update(GnssFix(float(g.t_s[j]), g.llh[j], g.pos_sigma_m[j], g.vel_n_mps[j], g.vel_sigma_mps[j])))
    return recs


def _diverge(fix):
    raise np.linalg.LinAlgError("Singular matrix")


def test_a_failing_hypothesis_is_dropped_with_an_event(short_ifa, monkeypatch) -> None:
    ss, imu, g, init = short_ifa
    al = InFlightAligner(init, ss.scenario.aircraft.gnss_lever_arm_m, IfaFilterConfig(), "add2", 0.01)
    _epochs(al, imu, g, [0])
    n = al.hypotheses
    bad = al.hyps[2]
    monkeypatch.setattr(bad, "_epoch", _diverge)
    rec = _epochs(al, imu, g, [1])[0]
    assert bad not in al.hyps and al.hypotheses <= n - 1 and al.hypotheses_failed == 1
    failed = [e for e in rec.events if e.kind == "failed"]
    assert len(failed) == 1 and failed[0].offset_deg == 120.0 and failed[0].t_s == g.t_s[1]
    assert "LinAlgError: Singular matrix" in failed[0].reason and "+120 deg failed" in str(failed[0])
    assert al.events[-len(rec.events):] == rec.events


def test_every_hypothesis_failing_is_a_numerical_failure_and_restores_the_state(short_ifa, monkeypatch) -> None:
    ss, imu, g, init = short_ifa
    al = InFlightAligner(init, ss.scenario.aircraft.gnss_lever_arm_m, IfaFilterConfig(heading_hypotheses=2), "add2", 0.01)
    _epochs(al, imu, g, [0])
    before = [(h.x.copy(), h.S.copy(), len(h.window)) for h in al.hyps]
    for h in al.hyps:
        monkeypatch.setattr(h, "_epoch", _diverge)
    with pytest.raises(NumericalFailure, match="every heading hypothesis") as ei:
        _epochs(al, imu, g, [1])
    assert ei.value.what == "IFA filter" and ei.value.t_s == g.t_s[1]
    assert al.hypotheses == 2 and al.hypotheses_failed == 0
    assert all(np.array_equal(h.x, x) and np.array_equal(h.S, S) and len(h.window) == nw for h, (x, S, nw) in zip(al.hyps, before))


def test_run_warns_about_a_failed_hypothesis(short_ifa, monkeypatch) -> None:
    """The batch run turns the events into warnings and counts them in the result."""
    ss, imu, g, init = short_ifa
    from dpos_core.ifa import pipeline

    real = pipeline._Engine.update

    def update(self, fix):
        if fix.t_s == g.t_s[2] and self is self._victim:
            raise NumericalFailure("diverged on purpose", what="IFA filter", t_s=fix.t_s)
        return real(self, fix)

    real_init = pipeline.InFlightAligner.__init__

    def init_(self, *a, **kw):
        real_init(self, *a, **kw)
        pipeline._Engine._victim = self.hyps[1]

    monkeypatch.setattr(pipeline._Engine, "update", update)
    monkeypatch.setattr(pipeline.InFlightAligner, "__init__", init_)
    monkeypatch.setattr(pipeline._Engine, "_victim", None, raising=False)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        res = run(imu, g, ss.scenario.aircraft.gnss_lever_arm_m, IfaFilterConfig(), "add2", init)
    msgs = [str(x.message) for x in w if "heading hypothesis" in str(x.message)]
    assert len(msgs) == 1 and "+60 deg failed" in msgs[0] and "diverged on purpose" in msgs[0]
    assert res.hypotheses_failed == 1 and res.chol_jitter_repairs == 0 and res.rejected == []
