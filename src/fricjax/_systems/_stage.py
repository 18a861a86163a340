"""A nanometre positioning stage under PID control with friction feed-forward, as a system `fj.simulate` runs.

amthor §III-IV: a 24.5 kg slider on ball-bearing guides, driven by voice-coil actuators, its position read by a
laser interferometer (0.1 nm resolution), controlled at 10 kHz by a PID controller plus a feed-forward of the
forces the motion needs; friction (rolling, with pre-rolling hysteresis) is almost all of them (1.15 N of
force against 0.07 N of inertia on a 10 um, 1 Hz sine). The feed-forward is an inverse model of the axis,
position -> force, whose linear parameters are adapted online by U-D factorised recursive least squares
(`fj.RecursiveLeastSquares`); it cut the tracking error by a factor above 25 (NRMSE 9.01 % -> 0.36 %).

Here the "true" axis is a mass with any fricjax friction model (GMS by default), and the compensators are:

- `"none"`: PID only;
- `"static"`: Coulomb + viscous friction and the inertia of the reference: `m a_r + Fc sign(v_r) + Fv v_r`;
- `"model"`: an inverse model linear in its parameters (the extended DNLRX of amthor eq. 8 with n = 0: Maxwell-slip
  elements with thresholds `Delta_i` on the position, the velocity, an offset; plus the nominal inertia; and, an
  addition of ours, Stribeck terms `direction exp(-(v / v_j)^2)` for a bank of widths `v_j`, which give the drop
  from static to sliding friction that rate-independent elements cannot), its parameters `theta` fixed
  (identified offline);
- `"adaptive"`: the same model with `theta` adapted online: after each sample the applied force less the
  inertia is regressed on the model's regressors of the measured motion (U-D RLS with forgetting), and the
  feed-forward evaluates the model on the reference.

**Discretisation** (sample time `dt`, force held over the sample): `v_{k+1} = v_k + dt (u_k - F_k) / m`,
`x_{k+1} = x_k + dt v_{k+1}` (symplectic Euler), then the friction model steps over the motion `x_k -> x_{k+1}`
to give `F_{k+1}`. The controller reads the position quantised to `resolution`.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._constraints import Fixed, FixedScalar, ParamLike, as_float_array, unwrap
from .._inputs import MotionSample
from .._metrics import numpy_rmse, numpy_std
from .._models._base import AbstractFrictionModel, AbstractSystem
from .._smoothing import is_concrete
from ._recursive import ud_update

Compensation = Literal["none", "static", "model", "adaptive"]


class StageCompensator(eqx.Module):
    """The friction feed-forward of a `PositioningStage` (see the module docstring for the four kinds).

    **Arguments:**

    - `kind`: `"none"`, `"static"`, `"model"` or `"adaptive"`.
    - `mass`: the nominal moving mass [kg] for the inertia feed-forward `m a_r`.
    - `Fc`, `Fv`: Coulomb force [N] and viscous coefficient [N s/m] (`"static"`).
    - `thresholds`: Maxwell-slip thresholds `Delta_i` [m] of the inverse model (`"model"`, `"adaptive"`).
    - `stribeck_velocities`: velocities `v_j` [m/s] of Stribeck regressors `mean_i(dbar_i) exp(-(v / v_j)^2)` (the
      drop from static to sliding friction, which rate-independent elements cannot give; a bank of widths keeps
      the model linear in its parameters). Default none.
    - `theta`: its parameters, `(M + J + 2,)`: element forces [N] at full deflection, Stribeck forces [N], viscous
      [N s/m], offset [N].
    - `forgetting`, `p0`: the recursive least squares' forgetting factor and initial covariance (`"adaptive"`).
    - `adapt_from`: the time [s] from which the adaptation runs (before it the model is used as given).
    - `feedforward_from`: the time [s] from which the feed-forward is applied (before it: PID only; amthor's
      Fig. 6 switches the compensator on during the run). Default 0.
    """

    kind: str = eqx.field(static=True)
    mass: Float[Array, ""]
    Fc: Float[Array, ""]
    Fv: Float[Array, ""]
    thresholds: Fixed[Float[Array, " M"]]
    stribeck_velocities: Fixed[Float[Array, " J"]]
    theta: Float[Array, " M+J+2"]
    forgetting: FixedScalar
    p0: FixedScalar
    adapt_from: FixedScalar
    feedforward_from: FixedScalar

    def __init__(
        self,
        kind: Compensation = "none",
        *,
        mass: ParamLike = 0.0,
        Fc: ParamLike = 0.0,
        Fv: ParamLike = 0.0,
        thresholds: Any = None,
        stribeck_velocities: Any = None,
        theta: Any = None,
        forgetting: ParamLike = 0.9995,
        p0: ParamLike = 1.0,
        adapt_from: ParamLike = 0.0,
        feedforward_from: ParamLike = 0.0,
    ):
        if kind not in ("none", "static", "model", "adaptive"):
            raise ValueError(f"StageCompensator: `kind` must be 'none', 'static', 'model' or 'adaptive', got {kind!r}.")
        thresholds = np.zeros(0) if thresholds is None else thresholds
        velocities = np.zeros(0) if stribeck_velocities is None else stribeck_velocities
        size = int(np.size(thresholds)) + int(np.size(velocities)) + 2
        theta = np.zeros(size) if theta is None else theta
        if kind in ("model", "adaptive") and np.size(thresholds) == 0:
            raise ValueError(f"StageCompensator: kind {kind!r} needs the inverse model's `thresholds` [m].")
        if np.shape(theta) != (size,):
            raise ValueError(
                f"StageCompensator: `theta` must have shape ({size},) (one force per threshold and per Stribeck "
                f"velocity, the viscous coefficient, the offset), got {np.shape(theta)}."
            )
        if is_concrete(thresholds) and not np.all(np.asarray(thresholds) > 0):
            raise ValueError("StageCompensator: `thresholds` must be positive displacements [m].")
        if is_concrete(velocities) and not np.all(np.asarray(velocities) > 0):
            raise ValueError("StageCompensator: `stribeck_velocities` must be positive velocities [m/s].")
        if is_concrete(forgetting) and not 0 < float(np.asarray(forgetting)) <= 1:
            raise ValueError(f"StageCompensator: `forgetting` must be in (0, 1], got {forgetting!r}.")
        self.kind = kind
        self.mass, self.Fc, self.Fv = as_float_array(mass), as_float_array(Fc), as_float_array(Fv)
        self.thresholds = Fixed(as_float_array(thresholds))
        self.stribeck_velocities = Fixed(as_float_array(velocities))
        self.theta = as_float_array(theta)
        self.forgetting, self.p0 = Fixed(as_float_array(forgetting)), Fixed(as_float_array(p0))
        self.adapt_from = Fixed(as_float_array(adapt_from))
        self.feedforward_from = Fixed(as_float_array(feedforward_from))

    @property
    def size(self) -> int:
        """The number of the inverse model's parameters."""
        return self.elements + int(np.shape(unwrap(self.stribeck_velocities))[0]) + 2

    @property
    def elements(self) -> int:
        """The number of Maxwell-slip elements of the inverse model."""
        return int(np.shape(unwrap(self.thresholds))[0])

    def regressors(self, deflection: Array, velocity: Array) -> Array:
        """The inverse model's regressors: the normalised element deflections, the Stribeck terms, the velocity,
        1 (parameters unwrapped)."""
        direction = jnp.mean(deflection) if deflection.shape[0] else jnp.sign(velocity)
        stribeck = direction * jnp.exp(-((velocity / unwrap(self.stribeck_velocities)) ** 2))
        return jnp.concatenate([deflection, stribeck, velocity[None], jnp.ones((1,), deflection.dtype)])


class StageState(eqx.Module):
    """The stage's state: true position `x` [m] and velocity `v` [m/s], the friction force `F` [N] and the friction
    model's state; the controller's integral [m s] and last error [m]; the reference's last position [m] and
    velocity [m/s]; the inverse model's element deflections on the reference and on the measured position
    (normalised), the last measured position [m]; the adapted parameters `theta` and their U-D covariance."""

    x: Array
    v: Array
    F: Array
    friction: Any  # the plant friction model's state: any pytree, as its `init_state` returns
    integral: Array
    error: Array
    reference: Array
    reference_velocity: Array
    ff_deflection: Array
    measured_deflection: Array
    measured: Array
    theta: Array
    U: Array
    d: Array
    t: Array


class PositioningStage(AbstractSystem):
    """A positioning stage (amthor §III-IV): mass, plant friction, PID control and a friction feed-forward.

    Input: `fj.InputRecord(dt=..., reference=x_r [m], friction_scale=...)` (`friction_scale`, optional, multiplies
    the plant friction: a step of +-20 % mid-run tests the adaptation). Output per sample: a dict with the true
    position `x`, the tracking error `error = x_r - x`, the applied force `u`, the feed-forward `u_ff`, the friction
    force `friction` [N] and the compensator's `theta`.

    **Arguments:**

    - `mass`: the moving mass [kg] (24.5 in amthor).
    - `friction`: the plant's friction, any fricjax friction model (position in, force out).
    - `kp`, `ki`, `kd`: PID gains [N/m], [N/(m s)], [N s/m]; the derivative acts on the error's difference.
    - `compensator`: a `StageCompensator` (default none: PID only).
    - `resolution`: the position sensor's quantisation [m] (0.1 nm in amthor; 0 for none).
    """

    mass: Float[Array, ""]
    friction: AbstractFrictionModel
    kp: Float[Array, ""]
    ki: Float[Array, ""]
    kd: Float[Array, ""]
    compensator: StageCompensator
    resolution: FixedScalar

    requires: ClassVar[frozenset[str]] = frozenset({"reference"})

    def __init__(
        self,
        mass: ParamLike,
        friction: AbstractFrictionModel,
        kp: ParamLike,
        ki: ParamLike,
        kd: ParamLike,
        compensator: StageCompensator | None = None,
        *,
        resolution: ParamLike = 0.0,
    ):
        if not isinstance(friction, AbstractFrictionModel):
            raise TypeError(f"PositioningStage: `friction` must be a fricjax friction model, got {type(friction)}.")
        if is_concrete(mass) and not float(np.asarray(mass)) > 0:
            raise ValueError(f"PositioningStage: `mass` must be positive [kg], got {mass!r}.")
        self.mass = as_float_array(mass)
        self.friction = friction
        self.kp, self.ki, self.kd = as_float_array(kp), as_float_array(ki), as_float_array(kd)
        self.compensator = StageCompensator() if compensator is None else compensator
        self.resolution = Fixed(as_float_array(resolution))

    def init_state(self) -> StageState:
        p = unwrap(self)
        zero = jnp.zeros((), p.mass.dtype)
        c = p.compensator
        m = c.elements
        return StageState(
            x=zero,
            v=zero,
            F=zero,
            friction=p.friction.init_state(),
            integral=zero,
            error=zero,
            reference=zero,
            reference_velocity=zero,
            ff_deflection=jnp.zeros((m,), zero.dtype),
            measured_deflection=jnp.zeros((m,), zero.dtype),
            measured=zero,
            theta=jnp.asarray(c.theta, zero.dtype),
            U=jnp.eye(c.size, dtype=zero.dtype),
            d=jnp.full((c.size,), c.p0, zero.dtype),
            t=zero,
        )

    def samples(self, inputs: Any) -> dict[str, Array]:
        signals = inputs.samples()
        if "friction_scale" not in signals:
            signals["friction_scale"] = jnp.ones_like(signals["reference"])
        return signals

    def step(self, state: StageState, sample: dict[str, Array]) -> tuple[StageState, dict[str, Array]]:
        p = unwrap(self)
        c = p.compensator
        dt, r = sample["dt"], sample["reference"]
        # the reference's motion (finite differences; 0 before the record) and the feed-forward
        v_r = (r - state.reference) / dt
        a_r = (v_r - state.reference_velocity) / dt
        ff_deflection = _deflect(state.ff_deflection, r - state.reference, c.thresholds)
        if c.kind == "none":
            u_ff = jnp.zeros_like(r)
        elif c.kind == "static":
            u_ff = c.mass * a_r + c.Fc * jnp.sign(v_r) + c.Fv * v_r
        else:
            u_ff = c.mass * a_r + jnp.dot(c.regressors(ff_deflection, v_r), state.theta)
        u_ff = jnp.where(state.t >= c.feedforward_from, u_ff, 0.0)
        # the controller reads the quantised position
        measured = _quantise(state.x, p.resolution)
        error = r - measured
        integral = state.integral + error * dt
        u = u_ff + p.kp * error + p.ki * integral + p.kd * (error - state.error) / dt
        # the plant: symplectic Euler with the force held, then the friction over the motion
        v = state.v + dt * (u - state.F) / p.mass
        x = state.x + dt * v
        friction_state, F = p.friction.step(state.friction, MotionSample(x=x, v=v, dx=x - state.x, dt=dt))
        F = F * sample["friction_scale"]
        # adaptation: the applied force less the reference's inertia, on the regressors of the measured motion
        measured_deflection = _deflect(state.measured_deflection, measured - state.measured, c.thresholds)
        theta, U, d = state.theta, state.U, state.d
        if c.kind == "adaptive":
            phi = c.regressors(measured_deflection, (measured - state.measured) / dt)
            gain, U_new, d_new = ud_update(state.U, state.d, phi, c.forgetting)
            on = state.t >= c.adapt_from
            target = u - c.mass * a_r
            theta = jnp.where(on, state.theta + gain * (target - jnp.dot(phi, state.theta)), state.theta)
            U, d = jnp.where(on, U_new, state.U), jnp.where(on, d_new, state.d)
        new_state = StageState(
            x=x,
            v=v,
            F=F,
            friction=friction_state,
            integral=integral,
            error=error,
            reference=r,
            reference_velocity=v_r,
            ff_deflection=ff_deflection,
            measured_deflection=measured_deflection,
            measured=measured,
            theta=theta,
            U=U,
            d=d,
            t=state.t + dt,
        )
        return new_state, {
            "x": state.x,
            "error": r - state.x,
            "u": u,
            "u_ff": u_ff,
            "friction": state.F,
            "theta": theta,
        }


def _deflect(deflection: Array, dx: Array, thresholds: Array) -> Array:
    """Maxwell-slip elements (play operators) on a displacement step: normalised deflections in [-1, 1]."""
    if thresholds.shape[0] == 0:
        return deflection
    return jnp.clip(deflection + dx / thresholds, -1.0, 1.0)


def _quantise(x: Array, resolution: Array) -> Array:
    return jnp.where(resolution > 0, resolution * jnp.round(x / jnp.where(resolution > 0, resolution, 1.0)), x)


def tracking_nrmse(error: Any, reference: Any) -> float:
    """The tracking error's RMS over the reference's RMS about its mean, in % (amthor's NRMSE of Fig. 6)."""
    return float(100.0 * numpy_rmse(error) / numpy_std(reference))  # scaled before squaring
