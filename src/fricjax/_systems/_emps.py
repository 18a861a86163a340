"""The EMPS plant (a mass with static friction driven by a force) and its open- and closed-loop simulation.

The Electro-Mechanical Positioning System benchmark (Janot, Gautier & Brunot 2019, *Data Set and Reference
Models of EMPS*; the emps-ensemble paper, eq. 1) is a rigid prismatic axis: its direct dynamic model is

    M q'' = gtau * vir - F_f(q') - offset

with `q` the load position [m], `vir` the drive command [V] (the controller output), `gtau` the drive gain
[N/V], `M` the moving mass [kg], `F_f` a static friction law [N] and `offset` a constant force [N]. In the
benchmark the axis runs in closed loop under the PD position controller

    nu(k) = kp * kv * (qg(k) - q(k)) - kv * (qf(k) - qf(k-1)) / dt,   qf(k) = (q(k) + q(k-1)) / 2,
    vir(k) = sat_{+-10 V}(nu(k)) (+ the pulse disturbance of the PULSES experiment),

sampled at 1 kHz, `vir(k)` held over the sample (zero-order hold). With these conventions the controller
reproduces the measured `vir` of `DATA_EMPS.mat` from the measured `qm` to 0.0037 V RMS, with no extra delay.

**Discretisation.** `vir` is held over each sample, so over a (sub-)step of length `h` the velocity obeys
`M v' = u - F(v)` with a constant applied force `u`. The step linearises the friction about the current
velocity, `F(v) ~ F(v_k) + F'(v_k) (v - v_k)`, and integrates the linearised equation exactly (an
exponential-Euler step):

    v_{k+1} = v_k + a h phi1(-lambda h),   q_{k+1} = q_k + h v_k + a h^2 phi2(-lambda h),

with `a = (u - F(v_k) - offset) / M`, `lambda = max(F'(v_k), 0) / M`, `phi1(z) = (e^z - 1) / z` and
`phi2(z) = (e^z - 1 - z) / z^2`. For Coulomb + viscous friction away from a velocity reversal this is the exact
solution (the viscous part is integrated exactly with the input held); it is unconditionally stable for any
dissipative slope, which keeps a smooth friction law (`Smooth(eps)` with a small `eps`, slope `Fc / eps`)
stable at the data's sample rate; negative slopes (a Stribeck dip) are treated explicitly. At a reversal with
the exact `sign`, the velocity chatters about zero by about `h Fc / M` (2e-4 m/s at 1 kHz on EMPS), which
`substeps` reduces. `F'` comes from `jax.jvp`, so the simulators work with any fricjax static law, and both are
one `lax.scan`, jit-compiled and differentiable with respect to every plant parameter.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._constraints import Parameter, ParamLike, as_float_array, model_dtype, positive, real, unwrap
from .._inputs import InputRecord
from .._metrics import rmse
from .._models._base import AbstractSystem
from .._models.physics._static import AbstractStaticFriction
from .._simulate import simulate
from .._smoothing import is_concrete
from .._validation import nonnegative_int, positive_int


class EMPSPlant(eqx.Module):
    """The EMPS axis: `M q'' = u - F_f(q') - offset`, `u = gtau * vir` the drive force [N].

    **Arguments:**

    - `mass`: moving mass `M` [kg] (> 0; about 95 kg on EMPS). Stored through a log reparametrisation.
    - `friction`: any fricjax static friction law (`CoulombViscous`, `Threlfall`, `Tustin`, `BoPavelescu`,
      symmetric or asymmetric, exact or smooth), or a `HybridFriction` (a law plus a network residual that may
      also read the position and the drive force). Its own `offset` is part of the friction force.
    - `offset`: an extra constant force [N] (default 0), added to the friction law's offset.

    The published IDIM-LS model of the benchmark (Janot et al. 2019) is

    ```python
    >>> import fricjax as fj
    >>> plant = fj.EMPSPlant(95.1089, fj.CoulombViscous(Fc=20.3935, Fv=203.5034, offset=-3.1648))
    >>> round(float(plant.resisting_force(0.1)), 4)
    37.579
    ```
    """

    mass: Parameter
    friction: AbstractStaticFriction
    offset: Float[Array, ""]

    def __init__(self, mass: ParamLike, friction: AbstractStaticFriction, offset: ParamLike = 0.0):
        if not isinstance(friction, AbstractStaticFriction):
            raise TypeError(
                "EMPSPlant: `friction` must be a fricjax static friction law (e.g. "
                f"fricjax.CoulombViscous(Fc=..., Fv=...)), got {type(friction).__name__}."
            )
        dtype = model_dtype(mass, offset)
        self.mass = positive(mass, "mass", dtype)
        self.friction = friction
        self.offset = real(offset, "offset", dtype)

    def resisting_force(self, v: ArrayLike, q: ArrayLike | None = None, force: ArrayLike | None = None) -> Array:
        """`F_f(v) + offset` [N] at velocity `v` [m/s] (the force the drive must overcome).

        A `HybridFriction` whose residual reads the position `q` [m] or the drive force `force` [N] gets them
        too (the simulators pass both); a static law ignores them."""
        p = unwrap(self)
        return p.friction.plant_force(v, q, force) + p.offset

    def acceleration(self, v: ArrayLike, force: ArrayLike, q: ArrayLike | None = None) -> Array:
        """`q'' = (force - F_f(v) - offset) / M` [m/s^2] for drive force `force` [N] (at position `q` [m])."""
        p = unwrap(self)
        return (jnp.asarray(force) - p.resisting_force(v, q, force)) / p.mass


class EMPSSimulation(NamedTuple):
    """A simulated EMPS record, each of shape `(T,)`, sampled at `t_k = k dt`.

    `q` position [m], `qd` velocity [m/s], `vir` the drive command [V] applied over `[t_k, t_k+1)` (in open
    loop the given input; in closed loop the saturated controller output plus any disturbance).
    """

    q: Float[Array, "T"]
    qd: Float[Array, "T"]
    vir: Float[Array, "T"]


def _phi12(z: Array) -> tuple[Array, Array]:
    """`phi1(z) = (e^z - 1) / z` and `phi2(z) = (e^z - 1 - z) / z^2` for `z <= 0`, NaN-free at `z = 0`."""
    small = jnp.abs(z) < 1e-2
    zs = jnp.where(small, -1.0, z)  # double-where: the division branch never sees z = 0
    em1 = jnp.expm1(zs)
    phi1 = jnp.where(small, 1.0 + z / 2 + z**2 / 6 + z**3 / 24, em1 / zs)
    phi2 = jnp.where(small, 0.5 + z / 6 + z**2 / 24 + z**3 / 120, (em1 - zs) / zs**2)
    return phi1, phi2


def _advance(plant: EMPSPlant, q: Array, v: Array, force: Array, h: Array, substeps: int) -> tuple[Array, Array]:
    """Advance `(q, v)` by `substeps` exponential-Euler steps of length `h` with the drive force held."""
    dtype = q.dtype
    mass = plant.mass.astype(dtype)

    def one(_: Any, state: tuple[Array, Array]) -> tuple[Array, Array]:
        q, v = state
        friction, slope = jax.jvp(lambda w: plant.resisting_force(w, q, force), (v,), (jnp.ones_like(v),))
        accel = (force - friction.astype(dtype)) / mass
        z = -jnp.maximum(slope.astype(dtype), 0.0) / mass * h
        phi1, phi2 = _phi12(z)
        return q + h * v + accel * h * h * phi2, v + accel * h * phi1

    if substeps == 1:
        return one(0, (q, v))
    return jax.lax.fori_loop(0, substeps, one, (q, v))


class EMPSOpenLoop(AbstractSystem):
    """The EMPS plant driven by a recorded command (no controller), as a model for `fj.simulate`.

    Input record: `fj.InputRecord(dt=..., vir=...)` (drive command [V], held over each sample). State:
    `(q, q')` [m, m/s]. Output at sample k: `(q(k), q'(k))`, then the plant is advanced to k+1 with the force
    `gtau * vir(k)` (`substeps` exponential-Euler steps; see the module docstring).

    **Arguments:** `plant` an `EMPSPlant`; `gtau` drive gain [N/V] (35.15 on EMPS); `substeps` integration steps
    per sample (static, default 1).
    """

    plant: EMPSPlant
    gtau: Float[Array, ""]
    substeps: int = eqx.field(static=True, default=1)

    requires: ClassVar[frozenset[str]] = frozenset({"vir"})

    def __init__(self, plant: EMPSPlant, gtau: ArrayLike, substeps: int = 1):
        _check_plant(plant)
        self.plant = plant
        self.gtau = _scalar(gtau, "gtau", None, unit="N/V", positive_only=True)
        self.substeps = _substeps(substeps, "EMPSOpenLoop")

    def init_state(self) -> tuple[Array, Array]:
        zero = jnp.zeros((), jnp.result_type(self.gtau))
        return zero, zero

    def step(self, state: tuple[Array, Array], sample: dict[str, Array]) -> tuple[Any, tuple[Array, Array]]:
        q, v = state
        force = self.gtau * sample["vir"]
        return _advance(self.plant, q, v, force, sample["dt"] / self.substeps, self.substeps), (q, v)


class EMPSClosedLoop(AbstractSystem):
    """The EMPS under its PD position controller, as a model for `fj.simulate`.

    Input record: `fj.InputRecord(dt=..., qg=..., disturbance=...)` (reference position [m], voltage [V]
    added after the saturation). State: `(q(k), q'(k), q(k-1), q(k-2))`. Output at sample k: `(q(k), q'(k),
    vir(k))` with `vir(k) = clip(kp kv (qg(k) - q(k)) - kv (qf(k) - qf(k-1)) / dt, -vmax, vmax) +
    disturbance(k)`, `qf(k) = (q(k) + q(k-1)) / 2` (Janot et al. 2019, §1.3); `vir(k)` is held while the plant
    advances to k+1. The state at rest is `(q0, 0, q0, q0)`: build it with `EMPSClosedLoop.rest_state(q0, qd0)`.

    **Arguments:** `plant`; `gtau` [N/V], `kp` [1/s], `kv` [V s/m] (on EMPS 35.15, 160.18, 243.45); `vmax`
    command saturation [V]; `substeps` (static).
    """

    plant: EMPSPlant
    gtau: Float[Array, ""]
    kp: Float[Array, ""]
    kv: Float[Array, ""]
    vmax: Float[Array, ""]
    substeps: int = eqx.field(static=True, default=1)

    requires: ClassVar[frozenset[str]] = frozenset({"qg", "disturbance"})

    def __init__(
        self,
        plant: EMPSPlant,
        gtau: ArrayLike,
        kp: ArrayLike,
        kv: ArrayLike,
        vmax: ArrayLike = 10.0,
        substeps: int = 1,
    ):
        _check_plant(plant)
        self.plant = plant
        self.gtau = _scalar(gtau, "gtau", None, unit="N/V", positive_only=True)
        self.kp = _scalar(kp, "kp", None, unit="1/s", positive_only=True)
        self.kv = _scalar(kv, "kv", None, unit="V s/m", positive_only=True)
        self.vmax = _scalar(vmax, "vmax", None, unit="V", positive_only=True)
        self.substeps = _substeps(substeps, "EMPSClosedLoop")

    def init_state(self) -> tuple[Array, Array, Array, Array]:
        return self.rest_state(jnp.zeros((), jnp.result_type(self.gtau)))

    @staticmethod
    def rest_state(q0: ArrayLike, qd0: ArrayLike = 0.0) -> tuple[Array, Array, Array, Array]:
        """The state `(q0, qd0, q0, q0)`: before `t_0` the position is `q0` (the velocity estimate starts at 0)."""
        q0 = jnp.asarray(q0)
        return q0, jnp.asarray(qd0, q0.dtype), q0, q0

    def step(self, state: tuple[Array, Array, Array, Array], sample: dict[str, Array]) -> tuple[Any, Any]:
        q, v, q_prev, q_prev2 = state  # q(k), q'(k), q(k-1), q(k-2)
        dt = sample["dt"]
        # (qf(k) - qf(k-1)) / dt with qf(k) = (q(k) + q(k-1)) / 2
        velocity_estimate = 0.5 * (q - q_prev2) / dt
        nu = self.kp * self.kv * (sample["qg"] - q) - self.kv * velocity_estimate
        vir = jnp.clip(nu, -self.vmax, self.vmax) + sample["disturbance"]
        q_next, v_next = _advance(self.plant, q, v, self.gtau * vir, dt / self.substeps, self.substeps)
        return (q_next, v_next, q, q_prev), (q, v, vir)


def _open_loop(
    plant: EMPSPlant, record: InputRecord, gtau: Array, q0: Array, qd0: Array, substeps: int
) -> EMPSSimulation:
    """Open-loop simulation of `record` (its `vir`) through `fj.simulate` (the public function and the fit)."""
    system = EMPSOpenLoop(plant, gtau, substeps)
    q, qd = simulate(system, record, (q0, qd0))
    return EMPSSimulation(q=q, qd=qd, vir=record.signals["vir"])


def _scalar(value: ArrayLike, name: str, dtype: Any, *, unit: str, positive_only: bool) -> Array:
    array = jnp.asarray(as_float_array(value, dtype), dtype)
    if array.ndim != 0:
        raise ValueError(f"`{name}` must be a scalar ({unit}), got shape {array.shape}.")
    if is_concrete(array):
        if not bool(np.isfinite(np.asarray(array))):
            raise ValueError(f"`{name}` must be finite ({unit}), got {value!r}.")
        if positive_only and not float(array) > 0:
            raise ValueError(f"`{name}` must be positive ({unit}), got {value!r}.")
    return array


def _substeps(value: Any, where: str) -> int:
    return positive_int(value, "substeps", where, hint="(integration steps per sample)")


def _check_plant(plant: Any) -> None:
    if not isinstance(plant, EMPSPlant):
        raise TypeError(f"`plant` must be an EMPSPlant(mass, friction, offset), got {type(plant).__name__}.")


def simulate_open_loop(
    plant: EMPSPlant,
    vir: ArrayLike,
    gtau: ArrayLike,
    dt: ArrayLike,
    q0: ArrayLike = 0.0,
    qd0: ArrayLike = 0.0,
    *,
    substeps: int = 1,
) -> EMPSSimulation:
    """Simulate the EMPS plant driven by a recorded command `vir` (no controller).

    Solves `M q'' = gtau * vir(t) - F_f(q') - offset` with `vir(k)` held over `[t_k, t_k+1)` (see the module
    docstring for the step). This is the input-output setting of the benchmark (u = `vir`, y = `q`); the plant
    is a pure integrator, so errors in the force model accumulate as a drift of the position.

    **Arguments:**

    - `plant`: an `EMPSPlant`.
    - `vir`: the drive command [V], shape `(T,)`; its dtype sets the simulation dtype.
    - `gtau`: drive gain [N/V] (> 0; 35.15 on EMPS).
    - `dt`: sample time [s] (> 0).
    - `q0`, `qd0`: position [m] and velocity [m/s] at `t_0`.
    - `substeps`: integration steps per sample (static; default 1).

    **Returns:** an `EMPSSimulation` `(q, qd, vir)`; `q[0] = q0`, `qd[0] = qd0`.

    Jit-compiled; differentiable with respect to the plant's parameters (and `vir`, `q0`, `qd0`).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> plant = fj.EMPSPlant(95.0, fj.CoulombViscous(Fc=20.0, Fv=200.0))
    >>> sim = fj.simulate_open_loop(plant, np.full(100, 2.0), gtau=35.15, dt=1e-3)
    >>> bool(sim.qd[-1] > 0)
    True
    ```
    """
    _check_plant(plant)
    record = InputRecord(dt, vir=vir)  # checks the signal (1-D, samples, finite) and dt (> 0) once
    dtype = record.dt.dtype
    return _open_loop(
        plant,
        record,
        _scalar(gtau, "gtau", dtype, unit="N/V", positive_only=True),
        _scalar(q0, "q0", dtype, unit="m", positive_only=False),
        _scalar(qd0, "qd0", dtype, unit="m/s", positive_only=False),
        _substeps(substeps, "simulate_open_loop"),
    )


def simulate_closed_loop(
    plant: EMPSPlant,
    qg: ArrayLike,
    gtau: ArrayLike,
    kp: ArrayLike,
    kv: ArrayLike,
    dt: ArrayLike,
    *,
    q0: ArrayLike = 0.0,
    qd0: ArrayLike = 0.0,
    disturbance: ArrayLike | None = None,
    vmax: ArrayLike = 10.0,
    substeps: int = 1,
) -> EMPSSimulation:
    """Simulate the EMPS under its PD position controller, tracking the reference `qg`.

    At each sample the controller reads the position `q(k)` and commands
    `vir(k) = clip(kp kv (qg(k) - q(k)) - kv (qf(k) - qf(k-1)) / dt, -vmax, vmax) + disturbance(k)`, with
    `qf(k) = (q(k) + q(k-1)) / 2` (Janot et al. 2019, §1.3); `vir(k)` is held over the sample while the plant
    is integrated to `q(k+1)`. Before `t_0` the position is `q0` (the velocity estimate starts at 0).

    `disturbance` is a voltage added *after* the saturation, as the pulse block of the official Simulink model
    does: for `DATA_EMPS_PULSES.mat` pass the record's `pulses_N` (in V); the measured `vir` of that file
    already contains the pulses, so its closed-loop reconstruction needs them added here.

    **Arguments:**

    - `plant`: an `EMPSPlant`.
    - `qg`: reference position [m], shape `(T,)`; its dtype sets the simulation dtype.
    - `gtau`: drive gain [N/V]; `kp`: position gain [1/s]; `kv`: velocity gain [V/(m/s)] (all > 0; on EMPS
      35.15, 160.18, 243.45).
    - `dt`: sample time [s] (> 0).
    - `q0`, `qd0`: initial position [m] and velocity [m/s].
    - `disturbance`: optional voltage [V] added to the saturated command, shape `(T,)`.
    - `vmax`: command saturation [V] (default 10).
    - `substeps`: plant integration steps per controller sample (static; default 1).

    **Returns:** an `EMPSSimulation` `(q, qd, vir)`; `vir` is the command actually applied.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> plant = fj.EMPSPlant(95.0, fj.CoulombViscous(Fc=20.0, Fv=200.0))
    >>> qg = np.linspace(0.0, 0.01, 2000)
    >>> sim = fj.simulate_closed_loop(plant, qg, gtau=35.15, kp=160.18, kv=243.45, dt=1e-3)
    >>> bool(abs(sim.q[-1] - 0.01) < 1e-4)
    True
    ```
    """
    _check_plant(plant)
    qg = as_float_array(qg)
    dtype = qg.dtype
    disturbance = jnp.zeros_like(qg) if disturbance is None else as_float_array(disturbance, dtype).astype(dtype)
    # checks the signals (1-D, same length, finite) and dt (> 0) once
    record = InputRecord(_scalar(dt, "dt", dtype, unit="s", positive_only=True), qg=qg, disturbance=disturbance)
    system = EMPSClosedLoop(
        plant,
        _scalar(gtau, "gtau", dtype, unit="N/V", positive_only=True),
        _scalar(kp, "kp", dtype, unit="1/s", positive_only=True),
        _scalar(kv, "kv", dtype, unit="V s/m", positive_only=True),
        _scalar(vmax, "vmax", dtype, unit="V", positive_only=True),
        _substeps(substeps, "simulate_closed_loop"),
    )
    state0 = system.rest_state(
        _scalar(q0, "q0", dtype, unit="m", positive_only=False),
        _scalar(qd0, "qd0", dtype, unit="m/s", positive_only=False),
    )
    q, qd, vir = simulate(system, record, state0)
    return EMPSSimulation(q=q, qd=qd, vir=vir)


def emps_open_loop_rmse_mm(y_true: ArrayLike, y_sim: ArrayLike, *, skip: int = 20) -> Array:
    """The benchmark's official score: simulation RMSE of the position in **millimetres** on `[skip:]`.

    `1000 * sqrt(mean((y_true[skip:] - y_sim[skip:])^2))` with positions in metres; the first `skip = 20`
    samples are the state-initialisation window of the official loader (`nonlinear_benchmarks.EMPS`).
    Jittable; reduces the last axis.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> float(fj.emps_open_loop_rmse_mm(np.zeros(30), np.full(30, 1e-3)))
    1.0
    ```
    """
    y_true, y_sim = jnp.asarray(y_true), jnp.asarray(y_sim)
    if y_true.shape != y_sim.shape:
        raise ValueError(f"`y_true` and `y_sim` must have the same shape, got {y_true.shape} and {y_sim.shape}.")
    skip = nonnegative_int(skip, "skip", "emps_open_loop_rmse_mm", hint="(samples)")
    if y_true.ndim < 1 or y_true.shape[-1] <= skip:
        raise ValueError(
            f"the records have {y_true.shape[-1] if y_true.ndim else 0} samples, not more than `skip={skip}`; "
            "give longer records."
        )
    return 1000.0 * rmse(y_true[..., skip:], y_sim[..., skip:])  # scaled before squaring
