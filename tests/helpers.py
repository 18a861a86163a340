"""Models and motions shared by the tests."""

from __future__ import annotations

import numpy as np

import fricjax as fj

DT = 1e-3


def lugre(
    Fc: float = 1.0, Fs: float = 1.5, vs: float = 1e-3, sigma0: float = 1e5, sigma1: float = 300.0, sigma2: float = 40.0
) -> fj.LuGre:
    """A smooth LuGre (eps 1e-5 m/s); its defaults are the true model of the record tests, other values a start."""
    stribeck = fj.ExponentialStribeck(Fc=Fc, Fs=Fs, vs=vs)
    return fj.LuGre(stribeck, sigma0=sigma0, sigma1=sigma1, sigma2=sigma2, smoothing=fj.Smooth(1e-5))


def presliding_to_sliding(n: int = 400, amplitude: float = 2e-3, dt: float = DT) -> fj.Motion:
    """A sine whose amplitude grows from pre-sliding (um) into gross sliding (mm), with reversals."""
    t = np.arange(n) * dt
    envelope = amplitude * (t / t[-1]) ** 2 + 1e-6
    x = envelope * np.sin(2 * np.pi * 4.0 * t / (n * dt))
    return fj.Motion.from_position(x, dt=dt)


def coulomb_viscous_record(samples: int = 600, frequency: float = 1.5) -> fj.FrictionData:
    """A smooth Coulomb + viscous law (Fc 1 N, Fv 30 N s/m) under a 1 mm sine of `frequency` [Hz] at 1 kHz."""
    t = np.arange(samples) * DT
    motion = fj.Motion.from_position(1e-3 * np.sin(2 * np.pi * frequency * t), dt=DT)
    truth = fj.CoulombViscous(1.0, 30.0, smoothing=fj.Smooth(1e-4))
    return fj.FrictionData(motion, np.asarray(fj.simulate(truth, motion)))


def stribeck() -> fj.ExponentialStribeck:
    return fj.ExponentialStribeck(Fc=1.0, Fs=1.5, vs=1e-3, delta=2.0)


def model_table() -> dict[str, fj.AbstractFrictionModel]:
    """One instance of every model family (exact mode), small enough for fast tests."""
    return {
        "coulomb": fj.Coulomb(Fc=1.0, offset=0.1),
        "coulomb_viscous_asym": fj.CoulombViscous(Fc=(1.0, 1.2), Fv=(50.0, 80.0)),
        "threlfall": fj.Threlfall(Fc=1.0, Fv=50.0, v0=2e-3),
        "tustin": fj.Tustin(Fc=1.0, Fs=1.5, vs=1e-3, Fv=50.0),
        "bo_pavelescu_asym": fj.BoPavelescu(Fc=(1.0, 1.1), Fs=(1.5, 1.4), vs=1e-3, delta=(2.0, 1.5), Fv=50.0),
        "dahl": fj.Dahl(sigma0=1e5, Fc=1.0),
        "dahl_alpha": fj.Dahl(sigma0=1e5, Fc=1.0, alpha=1.7),
        "lugre": fj.LuGre(stribeck(), sigma0=1e5, sigma1=300.0, sigma2=40.0, offset=0.05, z0=1e-6),
        "lugre_rational": fj.LuGre(
            fj.RationalStribeck(Fc=1.0, Fs=1.5, vs=1e-3, mu=2.0), sigma0=1e5, sigma1=300.0, sigma2=40.0
        ),
        "lugre_backlash": fj.LuGreBacklash(
            fj.ExponentialStribeck(Fc=(1.0, 0.8), Fs=(1.5, 1.2), vs=1e-3, delta=2.0),
            sigma0=1e5,
            sigma1=300.0,
            sigma2=40.0,
            gap=2e-4,
            offset=0.05,
            w0=1.01e-4,  # engaged (gap / 2 = 1e-4 m), the bristles deflected by 1 um
        ),
        "gms": fj.GMS(stribeck(), k=[4e4, 2e4, 1e4, 5e3], alpha=[0.4, 0.3, 0.2, 0.1], C=20.0, sigma2=40.0),
        "maxwell_nlr": fj.MaxwellSlip.nlr(k=[2e5, 1e5, 5e4], thresholds=[2e-6, 6e-6, 2e-5], offset=0.1),
        "maxwell_lr": fj.MaxwellSlip.lr(k=[2e5, 1e5, 5e4], max_deflection=2e-5),
        "maxwell_dlr": fj.MaxwellSlip.dlr(theta=np.linspace(0.1, 0.5, 9).reshape(3, 3), max_deflection=2e-5),
        "maxwell_dnlrx": fj.MaxwellSlip.dnlrx(
            thresholds=[2e-6, 6e-6, 2e-5], theta=np.linspace(0.1, 0.5, 9).reshape(3, 3), c=[1e3, -5e2]
        ),
    }


# smoothing widths that are "small" for each family: velocity (m/s), displacement (m), or dimensionless
SMOOTH_EPS = {
    "coulomb": 1e-4,
    "coulomb_viscous_asym": 1e-4,
    "threlfall": 1e-4,
    "tustin": 1e-4,
    "bo_pavelescu_asym": 1e-4,
    "dahl": 1e-4,
    "dahl_alpha": 1e-4,
    "lugre": 1e-4,
    "lugre_rational": 1e-4,
    "lugre_backlash": 1e-4,
    "gms": 1e-7,
    "maxwell_nlr": 1e-2,
    "maxwell_lr": 1e-2,
    "maxwell_dlr": 1e-2,
    "maxwell_dnlrx": 1e-2,
    # neural models: tanh / sigmoid networks have no switch (smooth == exact); the recurrent network's
    # piecewise-linear sigmoid is smoothed in its (dimensionless) drive
    "mlp_narx": 1e-2,
    "gsnn": 1e-2,
    "gsnn_exp": 1e-2,
    "gsnn_tanh": 1e-2,
    "avd": 1e-2,
    "rnn": 1e-2,
    "mlp_plays": 1e-2,
    "gsnn_plays": 1e-2,
}


def smooth(name: str, model: fj.AbstractFrictionModel) -> fj.AbstractFrictionModel:
    return fj.with_smoothing(model, fj.Smooth(SMOOTH_EPS[name]))


def neural_record(n: int = 300) -> fj.FrictionData:
    """A LuGre force record (pre-sliding into sliding) to normalise the neural models by."""
    motion = presliding_to_sliding(n)
    lugre = fj.LuGre(stribeck(), sigma0=1e5, sigma1=300.0, sigma2=40.0)
    return fj.FrictionData(motion, fj.simulate(lugre, motion))


def neural_table() -> dict[str, fj.AbstractFrictionModel]:
    """One small instance of each neural black-box model, with random weights large enough to be nonlinear."""
    import jax

    data = neural_record()
    key = jax.random.PRNGKey(7)
    reg = fj.NARXRegressors.from_data(data, ("x", "v", "a"), 1, 2)
    plays = fj.NARXRegressors.from_data(data, ("v",), 0, 1, plays=[2e-6, 1e-5, 5e-5])
    rnn = fj.RecurrentNetwork.init(data, 6, key=key, delays=(0, 5, 12), connectivity=0.4, input_weight=3.0)
    rnn = fj.RecurrentNetwork(
        rnn.alpha_raw, rnn.w, rnn.w0, rnn.v, np.linspace(-1.0, 1.0, 6), 0.1,
        connectivity=rnn.connectivity, signals=rnn.signals, delays=rnn.delays, input_mean=rnn.input_mean,
        input_scale=rnn.input_scale, output_mean=rnn.output_mean, output_scale=rnn.output_scale,
    )  # fmt: skip
    return {
        "mlp_narx": _bigger_output(fj.MLPNARX.init(reg, 5, key=key)),
        "gsnn": _bigger_output(fj.GSNN.init(reg, 3, key=key)),
        "gsnn_exp": _bigger_output(fj.GSNN.init(reg, 2, key=key, denominator="exp")),
        "gsnn_tanh": _bigger_output(fj.GSNN.init(reg, 2, key=key, denominator="tanh", bound=0.3)),
        "avd": _bigger_output(fj.AVDNetwork(data, 4, key=key)),
        "mlp_plays": _bigger_output(fj.MLPNARX.init(plays, 4, key=key, linear=True)),
        "gsnn_plays": _with_linear(_bigger_output(fj.GSNN.init(plays, 3, key=key, linear=True))),
        "rnn": rnn,
    }


def _with_linear(model):
    """A nonzero linear part, so that its terms are exercised."""
    import equinox as eqx

    return eqx.tree_at(lambda m: m.theta, model, 0.3 * np.cos(np.arange(model.theta.size)))


def _bigger_output(model):
    """Output weights of order 1 (the random initialisation's are 0.1 / sqrt(width), nearly linear outputs)."""
    import equinox as eqx

    return eqx.tree_at(lambda m: m.d, model, model.d * 10.0)
