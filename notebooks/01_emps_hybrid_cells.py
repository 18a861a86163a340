# Cells to append to notebooks/01_emps.ipynb (after its last cell): the grey + black-box hybrid, ensembles and
# the closed loop. They reuse `train`, `test`, `fitted` (the open-loop Coulomb + viscous fit), `reference`,
# `SMOKE`, `STEPS`, `np`, `plt` and `fj` from the notebook's earlier cells.

# %% [markdown]
# ## Grey + black-box hybrid: the law plus a small network on the force path
#
# `fj.HybridFriction` adds to a static law a one-hidden-layer tanh network of the velocity and the position,
# `F = F_law(v) + d·tanh(W x + b)` (x normalised), inside the same `EMPSPlant`: with `d = 0` it *is* the law, so
# training starts from the open-loop fit and the official simulator and loss run unchanged. `fj.fit_emps_hybrid`
# trains it by the official free-run error (Adam through the simulator's `lax.scan`), here on the first 70 % of
# the training file, the last 30 % held out to compare the physics-free and physics-frozen variants. The test file
# is only scored.

# %%
HYBRID_STEPS = 20 if SMOKE else 200
start = fitted.plant  # the open-loop Coulomb + viscous plant of the cell above
hybrids = {
    name: fj.fit_emps_hybrid(
        train, start, inputs=("v", "q"), freeze_physics=frozen, steps=HYBRID_STEPS, learning_rate=rate
    )
    for name, frozen, rate in (("physics free", False, 3e-3), ("physics frozen", True, 1e-2))
}
print(f"{'model':<30}{'held-out tail [mm]':>20}{'train [mm]':>12}{'test [mm]':>11}")
tail = fj.split_emps_record(train, int(round(0.7 * train.length)))
print(
    f"{'open-loop fit (physics)':<30}{fj.score_emps_open_loop(start, tail):20.2f}"
    f"{fj.score_emps_open_loop(start, train):12.2f}{fj.score_emps_open_loop(start, test):11.2f}"
)
for name, h in hybrids.items():
    print(
        f"{'hybrid, ' + name:<30}{h.val_rmse_mm:20.2f}"
        f"{fj.score_emps_open_loop(h.plant, train):12.2f}{fj.score_emps_open_loop(h.plant, test):11.2f}"
    )
chosen = min(hybrids, key=lambda name: hybrids[name].val_rmse_mm)  # chosen on the held-out tail only
hybrid = hybrids[chosen].plant
print("chosen on the held-out tail:", chosen)

# %% [markdown]
# The residual the network learned, at the mean position, beside the law it corrects:

# %%
v = np.linspace(-0.14, 0.14, 561)
law = fj.exact(start)
plt.figure(figsize=(8, 4.5))
plt.plot(v, law.resisting_force(v), label="open-loop fit (law)")
q_mid = float(np.mean(train.qm))
plt.plot(v, hybrid.resisting_force(v, np.full_like(v, q_mid)), label=f"hybrid ({chosen}), q = {1e3 * q_mid:.0f} mm")
plt.xlabel("velocity [m/s]")
plt.ylabel("friction + offset [N]")
plt.legend()
plt.show()

# %% [markdown]
# ## Ensembles of simulated positions
#
# As the emps-ensemble paper's EGBB (eq. 16), the ensembles combine the members' simulated **positions**:
# the average, least-squares weights with an intercept (free or non-negative), and PRESS forward selection, the
# weights fitted on the training file only.

# %%
members = {"Coulomb + viscous": start, **{f"hybrid, {name}": h.plant for name, h in hybrids.items()}}
plants = list(members.values())
print(f"{'ensemble':<12}{'train [mm]':>12}{'test [mm]':>11}  weights")
for method in ("average", "lstsq", "nonnegative", "press"):
    ens = fj.fit_emps_ensemble(plants, train, method)
    names = [list(members)[i] for i in ens.indices]
    weights = ", ".join(f"{n}: {w:.2f}" for n, w in zip(names, np.asarray(ens.ensemble.weights), strict=True))
    print(f"{method:<12}{ens.ensemble.score(train):12.2f}{ens.ensemble.score(test):11.2f}  {weights}")

# %% [markdown]
# ## Closed loop
#
# Under the PD controller every model tracks the reference closely: relative errors [%] of position, velocity and
# force against the filtered measurements (Janot et al. publish 0.0138 % / 0.0080 % position error for their
# model on the training / test file, on the Simulink time base; the same model gives 0.0010 % / 0.0016 % here).

# %%
print(f"{'model':<30}{'position train / test [%]':>28}{'velocity':>18}{'force':>16}")
for name, plant in {"published reference": reference, **members}.items():
    a, b = fj.emps_closed_loop_errors(plant, train), fj.emps_closed_loop_errors(plant, test)
    print(
        f"{name:<30}{a['position_pct']:14.4f} / {b['position_pct']:.4f}"
        f"{a['velocity_pct']:10.3f} / {b['velocity_pct']:.3f}{a['force_pct']:8.2f} / {b['force_pct']:.2f}"
    )

# %%
# the zero-residual start is the physics plant, and every closed-loop model tracks to better than 0.01 %
assert fj.score_emps_open_loop(hybrids["physics frozen"].start, test) == fj.score_emps_open_loop(start, test)
assert all(np.isfinite(h.val_rmse_mm) for h in hybrids.values())
assert fj.emps_closed_loop_errors(hybrid, test)["position_pct"] < 0.01
