"""The compiled SINS/SAR model (dpos_core/sar/_model_kernel.py behind SarModel.f, h and project)
against the numpy formulas it replaced (kept here as the reference), on random particles spread
well beyond the filters' clouds, over every step of a short paper_sar run."""

from __future__ import annotations

import numpy as np
import pytest

from dpos_core import earth
from dpos_core.attitude import cross, quat_mul, quat_normalize, quat_to_dcm, rotvec_to_quat, wrap_angle
from dpos_core.evaluation.sar import problem
from dpos_core.sar.model import DP, DV, EPS, NAB, Q_ATT, SarModel, _dllh_to_dp, _dp_to_dllh, _frame_rate, heading_of
from dpos_core.sim.scenario import load_scenario
from dpos_core.sim.session import SimulatedSession


def _f_numpy(m: SarModel, k: int, x: np.ndarray) -> np.ndarray:
    """SarModel.f as it was written in numpy (e4cce13)."""
    tr = m.track
    dt = float(tr.dt_s[k])
    q, dv, dp, eps, nab = x[..., Q_ATT], x[..., DV], x[..., DP], x[..., EPS], x[..., NAB]
    llh_i, v_i, C_i = tr.llh_mid[k], tr.vel_mid_n_mps[k], tr.C_nb_mid[k]
    dllh = _dp_to_dllh(dp, tr.llh[k])
    llh_t = llh_i - dllh
    v_t = v_i - dv
    wie_i, wen_i = _frame_rate(llh_i, v_i)
    wie_t, wen_t = _frame_rate(llh_t, v_t)
    dw = eps @ C_i.T
    q1 = quat_mul(quat_mul(rotvec_to_quat((dw - (wie_i + wen_i)) * dt), q), rotvec_to_quat((wie_t + wen_t) * dt))
    C = quat_to_dcm(quat_normalize(q))
    dvsf = tr.dv_sf_n_mps[k]
    CT_dvsf = np.einsum("...ji,j->...i", C, dvsf)
    CT_nab = np.einsum("...ji,...j->...i", C, nab @ C_i.T)
    cor = cross(2.0 * wie_i + wen_i, v_i) - cross(2.0 * wie_t + wen_t, v_t)
    dg = earth.gravity_n(llh_i[0], llh_i[2]) - earth.gravity_n(llh_t[..., 0], llh_t[..., 2])
    dv1 = dv + (dvsf - CT_dvsf) + CT_nab * dt - cor * dt + dg * dt
    v_tm = v_i - 0.5 * (dv + dv1)
    rate = earth.llh_rate(llh_i[0], llh_i[2], v_i) - earth.llh_rate(llh_t[..., 0], llh_t[..., 2], v_tm)
    dp1 = _dllh_to_dp(dllh + rate * dt, tr.llh[k + 1])
    out = np.empty(x.shape)
    out[..., Q_ATT] = quat_normalize(q1)
    out[..., DV] = dv1
    out[..., DP] = dp1
    out[..., EPS] = eps
    out[..., NAB] = nab
    return out


def _h_numpy(m: SarModel, k: int, x: np.ndarray) -> np.ndarray:
    """SarModel.h's SAR rows as they were written in numpy (e4cce13)."""
    C_true = np.swapaxes(quat_to_dcm(quat_normalize(x[..., Q_ATT])), -1, -2) @ m.track.C_nb[k]
    out = np.empty(x.shape[:-1] + (4,))
    out[..., 0] = wrap_angle(heading_of(m.track.C_nb[k]) - heading_of(C_true))
    out[..., 1:4] = x[..., DP]
    return out


@pytest.fixture(scope="module")
def model() -> SarModel:
    return problem(SimulatedSession(load_scenario("paper_sar"), 2, duration_s=120.0)).model


def _particles(rng: np.random.Generator, n: int) -> np.ndarray:
    """States (n, 16) far wider than a filter's: attitude errors of degrees (some with a negative
    scalar part, unnormalized), 5 m/s, 500 m, 10x the turn-on biases."""
    x = np.empty((n, 16))
    x[:, 0] = rng.choice([-1.0, 1.0], n) * (1.0 + 0.01 * rng.standard_normal(n))
    x[:, 1:4] = 0.03 * rng.standard_normal((n, 3))
    x[:, 4:7] = 5.0 * rng.standard_normal((n, 3))
    x[:, 7:10] = 500.0 * rng.standard_normal((n, 3))
    x[:, 10:13] = 1e-4 * rng.standard_normal((n, 3))
    x[:, 13:16] = 1e-2 * rng.standard_normal((n, 3))
    return x


def test_f_equals_the_numpy_formulas(model: SarModel) -> None:
    rng = np.random.default_rng(7)
    for k in range(model.n_epochs - 1):
        x = _particles(rng, 50)
        ref = _f_numpy(model, k, x)
        new = model.f(k, x)
        assert not np.shares_memory(new, x)
        # rtol 1e-12, and 1e-15 of each component's scale where a component is near zero
        tol = 1e-12 * np.abs(ref) + 1e-15 * np.max(np.abs(ref), axis=0)
        assert np.all(np.abs(new - ref) <= tol), (k, np.max(np.abs(new - ref) / tol))
    # leading axes and one state (the Gaussian filters' call) keep their shape
    x = _particles(rng, 6).reshape(2, 3, 16)
    np.testing.assert_allclose(model.f(3, x), _f_numpy(model, 3, x), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(model.f(3, x[0, 0]), _f_numpy(model, 3, x[0, 0]), rtol=1e-12, atol=1e-18)


def test_h_equals_the_numpy_formulas(model: SarModel) -> None:
    rng = np.random.default_rng(8)
    sar = np.flatnonzero(model.meas.sar)
    assert sar.size > 10
    for k in sar:
        x = _particles(rng, 50)
        np.testing.assert_allclose(model.h(k, x), _h_numpy(model, k, x), rtol=1e-12, atol=1e-14)
    x = _particles(rng, 4)
    x[1, 0] = np.nan
    x[2, 2] = np.inf
    out = model.h(int(sar[0]), x)
    assert np.isnan(out[1, 0]) and np.isnan(out[2, 0]) and np.all(np.isfinite(out[[0, 3]]))
    np.testing.assert_array_equal(out[:, 1:], x[:, DP])
    np.testing.assert_allclose(model.h(int(sar[0]), x[0]), _h_numpy(model, int(sar[0]), x[0]), rtol=1e-12, atol=1e-14)
    no_fix = int(np.flatnonzero(~model.meas.sar)[0])
    np.testing.assert_array_equal(model.h(no_fix, x), x[:, 9:10])


def test_project_normalizes_the_quaternion_only() -> None:
    m = SarModel.__new__(SarModel)  # project uses no track
    x = _particles(np.random.default_rng(9), 40)
    out = m.project(x)
    np.testing.assert_allclose(out[:, Q_ATT], quat_normalize(x[:, Q_ATT]), rtol=1e-15, atol=1e-17)
    assert np.all(out[:, 0] >= 0.0)
    np.testing.assert_array_equal(out[:, 4:], x[:, 4:])
    assert not np.shares_memory(out, x)


def test_residual_wraps_the_heading_as_wrap_angle(model: SarModel) -> None:
    rng = np.random.default_rng(10)
    y = np.array([3.1, 5.0, -7.0, 2.0])
    hx = np.column_stack([rng.uniform(-20.0, 20.0, 200), rng.standard_normal((200, 3))])
    hx[:4, 0] = [3.1 - np.pi, 3.1 + np.pi, 3.1 - 3 * np.pi, 3.1]  # at the wrap points
    ref = y - hx
    ref[:, 0] = wrap_angle(ref[:, 0])
    out = model.residual(y, hx)
    np.testing.assert_array_equal(out, ref)
    assert np.all((out[:, 0] > -np.pi) & (out[:, 0] <= np.pi))
    np.testing.assert_array_equal(model.residual(y, hx[5]), ref[5])
    np.testing.assert_array_equal(model.residual(y[3:], hx[:, 3:]), ref[:, 3:])  # the barometer row: no wrap
    assert np.isnan(model.residual(y, np.full(4, np.nan))[0])


def test_kernel_mod_two_pi_is_numpys_mod() -> None:
    """The kernel's ``a % 2 pi`` without fmod on (-2 pi, 4 pi) equals np.mod bit for bit, at the
    branch edges and beyond them."""
    from dpos_core.sar._model_kernel import _mod_two_pi

    tp = 2.0 * np.pi
    edges = np.array([0.0, -0.0, tp, -tp, 2 * tp, -2 * tp, np.pi, -np.pi, 3 * np.pi, 1e-300, -1e-300, 7.0, -7.0, 20.0,
                      -20.0, 1e9, np.nan, np.inf, -np.inf])
    a = np.concatenate([edges, np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf),
                        np.random.default_rng(11).uniform(-15.0, 30.0, 2000)])
    with np.errstate(invalid="ignore"):
        ref = np.mod(a, tp)
    out = np.array([_mod_two_pi(float(v)) for v in a])
    np.testing.assert_array_equal(out, ref)
    np.testing.assert_array_equal(np.signbit(out), np.signbit(ref))


def test_loglik_is_gauss_logpdf_of_the_residual(model: SarModel) -> None:
    """SarModel.loglik (the particle filters' weights in one pass) equals the generic
    ``gauss_logpdf(residual(y, h(x)), R)`` at epochs with and without a SAR fix."""
    from dpos_core.filters.linalg import gauss_logpdf

    rng = np.random.default_rng(12)
    sar = np.flatnonzero(model.meas.sar)
    no_fix = np.flatnonzero(~model.meas.sar)
    assert sar.size and no_fix.size
    for k in np.concatenate([sar[::5], no_fix[::5]]):
        x = _particles(rng, 64)
        x[:, 1:4] *= 0.01  # attitude errors of arcminutes: the likelihood's own scale
        x[:, 7:10] *= 0.02
        ref = gauss_logpdf(model.residual(model.y(k), model.h(k, x)), model.R(k))
        np.testing.assert_allclose(model.loglik(k, x), ref, rtol=1e-13, atol=1e-12)
    x = _particles(rng, 3)
    x[1, 0] = np.nan
    assert np.isnan(model.loglik(int(sar[0]), x)[1])
    with pytest.raises(ValueError, match="loglik"):
        model.loglik(int(sar[0]), x[0])
