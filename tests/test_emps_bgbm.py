"""EMPS BGBM (emps-ensemble §3.2): the grey-box free run plus an output-error model of its error.

Synthetic records: the true plant's response with a known linear filter of the force added to the position, so
the fitted error model must find that filter; the benchmark's smoke run on the real files is in the slow tier
(tests/test_emps_hybrid.py runs `emps.py --hybrid --smoke`, which includes the BGBM lines).
"""

import numpy as np
import pytest
import scipy.signal

import fricjax as fj
from fricjax import (
    EMPSRecord,
)
from fricjax.emps import (
    fit_emps_bgbm,
    predict_emps_open_loop,
)

GTAU, DT = 35.1507, 1e-3
TRUTH = fj.EMPSPlant(95.0, fj.CoulombViscous(Fc=20.0, Fv=200.0, offset=-3.0, smoothing=fj.Smooth(1e-3)))

A_TRUE = np.poly([0.97, 0.6])  # a stable second-order denominator
B_TRUE = np.array([2e-6, -1e-6, 0.5e-6])  # m per N of drive force


@pytest.fixture(scope="module")
def records() -> tuple[EMPSRecord, EMPSRecord]:
    t = np.arange(900) * DT
    rich = scipy.signal.lfilter([0.2], [1.0, -0.8], np.random.default_rng(1).normal(size=t.size))  # excites B / A
    vir = 1.2 * np.sin(2 * np.pi * 1.7 * t) + 0.6 * np.sin(2 * np.pi * 6.1 * t + 1.0) + 0.3 + rich
    vir[:20] = 0.0  # so the added error is zero on the initialisation window and the grey box starts as before
    q = np.asarray(fj.simulate_open_loop(TRUTH, vir, GTAU, DT, q0=0.02, qd0=0.01).q)
    fields = dict(t=t, vir=vir, force=GTAU * vir, pulses=None, gtau=GTAU, kp=160.18, kv=243.45, dt=DT, name="syn")
    base = EMPSRecord(qm=q, qg=q, **fields)
    q1 = np.asarray(predict_emps_open_loop(TRUTH, base).q)
    e1 = scipy.signal.lfilter(B_TRUE, A_TRUE, base.force)  # the "unmodelled" error, from rest at sample 0
    with_error = EMPSRecord(qm=q1 + e1, qg=q1 + e1, **fields)
    return base, with_error


def test_any_reflection_coefficients_give_a_stable_monic_denominator():
    rng = np.random.default_rng(0)
    for order in (1, 2, 5):
        raw = rng.normal(scale=2.0, size=order)
        model = fj.emps.EMPSErrorModel(TRUTH, raw, np.zeros((1, order + 1)), np.ones(1), ("force",))
        a = np.asarray(model.denominator)
        assert a[0] == 1.0 and a.shape == (order + 1,)
        assert np.max(np.abs(np.roots(a))) < 1.0
    # first order: A = 1 + tanh(r) q^-1
    one = fj.emps.EMPSErrorModel(TRUTH, np.array([0.3]), np.zeros((1, 2)), np.ones(1), ("force",))
    np.testing.assert_allclose(np.asarray(one.denominator), [1.0, np.tanh(0.3)])


@pytest.mark.slow  # a few seconds (a subprocess or a fit): the fast tier stays under 5 minutes
def test_recovers_a_known_error_filter_of_the_force(records):
    base, record = records
    start_mm = fj.emps.score_emps_open_loop(TRUTH, record)
    fitted = fit_emps_bgbm(record, TRUTH, inputs=("force",), order=2, validation=None, steps=100)
    model = fitted.model
    assert start_mm > 0.5  # the error the grey box cannot explain, in mm
    assert fitted.train_rmse_mm < 1e-3 * start_mm
    np.testing.assert_allclose(np.asarray(model.denominator), A_TRUE, atol=1e-5)
    b = np.asarray(model.numerators[0]) / float(model.scales[0])
    np.testing.assert_allclose(b, B_TRUE, rtol=1e-3, atol=1e-9)
    # y2 = y1 + e1_hat, and without error the BGBM is the grey box
    q1 = np.asarray(predict_emps_open_loop(TRUTH, record).q)
    np.testing.assert_allclose(np.asarray(model.predict(record)), q1 + np.asarray(model.error(record)))
    clean = fit_emps_bgbm(base, TRUTH, inputs=("force", "qd"), order=1, validation=0.3, steps=20)
    assert clean.train_rmse_mm < 1e-4  # mm
    assert clean.val_rmse_mm == pytest.approx(clean.val_physics_mm, abs=1e-3)  # the tail's own start error stays


@pytest.mark.slow  # about 2.5 s (a second fit)
def test_validation_tail_is_scored_from_its_own_window(records):
    _, record = records
    fitted = fit_emps_bgbm(record, TRUTH, inputs=("force",), order=2, validation=0.3, steps=100)
    tail = fj.emps.split_emps_record(record, int(round(0.7 * record.length)))
    assert fitted.val_rmse_mm == pytest.approx(fitted.model.score(tail))
    assert fitted.val_physics_mm == pytest.approx(fj.emps.score_emps_open_loop(TRUTH, tail))
    assert fitted.result in ("successful", "max_steps")


def test_argument_errors(records):
    _, record = records
    with pytest.raises(ValueError, match="inputs"):
        fit_emps_bgbm(record, TRUTH, inputs=("velocity",))
    with pytest.raises(ValueError, match="inputs"):
        fit_emps_bgbm(record, TRUTH, inputs=("force", "force"))
    with pytest.raises(ValueError, match="order"):
        fit_emps_bgbm(record, TRUTH, order=-1)
    with pytest.raises(ValueError, match="pole"):
        fit_emps_bgbm(record, TRUTH, pole=1.0)
    with pytest.raises(ValueError, match="validation"):
        fit_emps_bgbm(record, TRUTH, validation=1.5)
    with pytest.raises(TypeError):
        fit_emps_bgbm(record.qm, TRUTH)
