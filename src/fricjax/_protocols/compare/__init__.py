"""The identification exercise of the papers as one function: fit a set of models to a record, score them in
exact mode on held-out data, add ensembles, and report (parlitz2004 Fig. 6, worden2007 Fig. 11, the kernel
paper's Table 1). The public namespace is `fricjax.compare`; `fricjax compare` runs it from the command line.

`default_models(settings)` is the recipe registry: for each model name, a start built from the training record
(`DataScales`: force levels, pre-sliding stiffness, breakaway displacement; the networks normalise by the record
itself) and a fit recipe. Physics models (`PHYSICS_MODELS`, fitted by default): Levenberg-Marquardt with the
linear parameters solved by least squares where the model allows (static curve, LuGre, Maxwell-slip); GMS from
`fj.initial_guess`'s data-driven start with 256 starts screened by their loss, the best 4 fitted (its element count
read off the record, `fj.element_count`, and kept above 4 only where the validation part prefers it). Neural
models (`NEURAL_MODELS`): the output layer by least squares, then output error (`neural_models`).
Linear-in-parameters models (`LINEAR_MODELS`): term selection, then output error.

One job per module, each depending only on those before it:

- `_settings`: `DataScales`, `FitSettings`, `RESULT_CODES`, `CompareError`;
- `_records`: `Split`, `TrainingRecords` (several records), `TestRecord`, `LoadedRecord` and the records named on
  the command line;
- `_scoring`: exact-mode free runs and scores, `ModelScore` (a row of the table), `paired_validation_gain`;
- `_recipes`: `ModelSpec` and the fit recipes shared by the families; `_physics_recipes`, `_blackbox_recipes`:
  each family's starts and fits; `_registry`: the model names and `default_models`;
- `_config`: `CompareConfig` (a run's configuration, validated; errors name its fields, `as_flags` shows them as
  the command line's flags) and `load_records` (its records loaded, checked and split: `CompareRecords`);
- `_ensembles`: `add_ensembles`; `_figures`: the figures; `_output`: the output folder and strict JSON;
- `_report`: the table, `report.json` and the `Report` a run returns and writes; `_emps_table`: `--data emps`;
- `_run`: `fit_and_score` and `run_compare` (a `CompareConfig` in, a `Report` out), the command from end to end.
"""
