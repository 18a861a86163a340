"""`fricjax predict` (issue 55, item 1): saved models run on records they were not fitted on, scored exactly as
`fricjax compare` scores its test records (MATLAB's `compare(data, model)`): the initialisation window estimates the
record's offset and the model's initial state, the rest runs free; predictions (CSV), figures and a report."""

from __future__ import annotations

import json

import numpy as np
import pytest

import fricjax as fj

DT = 5e-4


def _record(path, seed: int, offset: float = 0.0):
    data = fj.make_tribometer("mixed", seed=seed, duration=1.0).full
    t = np.arange(data.length) * DT
    x = np.asarray(data.motion.samples().x)
    np.savetxt(path, np.c_[t, x, np.asarray(data.force) + offset], delimiter=",", header="t,x,force", comments="")
    return path


def test_predict_scores_a_saved_model_as_compare_scores_a_test_record(tmp_path, capsys):
    import matplotlib
    import matplotlib.pyplot as plt

    backend = matplotlib.get_backend()
    matplotlib.use("svg")  # a backend other than Agg, as a notebook's inline one: writing figures must leave it be
    open_figures = plt.get_fignums()  # an earlier test's, in this process
    try:
        _predict_and_check(tmp_path, capsys)
        # the figures were files, not pyplot's: a notebook that ran the command still shows its own figures
        assert matplotlib.get_backend() == "svg" and plt.get_fignums() == open_figures
    finally:
        matplotlib.use(backend)


def _predict_and_check(tmp_path, capsys):
    record = _record(tmp_path / "new.csv", seed=3, offset=0.2)
    model = fj.LuGre(fj.ExponentialStribeck(Fc=1.0, Fs=1.3, vs=1e-3), sigma0=1e5, sigma1=300.0, sigma2=0.5)
    fj.save_model(tmp_path / "lugre.eqx", model)
    out = tmp_path / "out"
    code = fj.main(["predict", "--model", str(tmp_path / "lugre.eqx"), "--data", str(record), "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    report = json.loads((out / "report.json").read_text())
    (score,) = report["scores"]
    test = fj.compare.TestRecord.whole(fj.compare.load_record_spec(str(record)))
    expected, _ = fj.compare.score_prediction(fj.compare.predict_test_record(model, test), test)
    assert score["nmse"] == pytest.approx(expected.nmse, rel=1e-12) and score["model"] == "lugre"
    assert f"{expected.nmse:.4f}" in printed.out
    table = np.genfromtxt(out / "predictions.csv", delimiter=",", names=True)
    assert table.dtype.names[:4] == ("t_s", "x_m", "force_N", "scored") and "lugre_N" in table.dtype.names
    assert int(table["scored"].sum()) == test.record.length - test.scored_start
    assert {p.name for p in out.iterdir()} >= {
        "report.json",
        "predictions.csv",
        "test_errors.png",
        "hysteresis_loops.png",
    }
    assert any(out.glob("residuals*.png")), sorted(p.name for p in out.iterdir())


def test_predict_refuses_bad_input_in_one_line(tmp_path, capsys):
    record = _record(tmp_path / "new.csv", seed=3)
    (tmp_path / "not_a_model.eqx").write_text("hello")
    fj.save_model(tmp_path / "coulomb.eqx", fj.Coulomb(Fc=1.0))
    cases = [
        (["--model", str(tmp_path / "missing.eqx"), "--data", str(record)], "no such file"),
        (["--model", str(tmp_path / "coulomb.eqx"), "--data", str(record), "--init-window", "-5"], "--init-window"),
        (["--model", str(tmp_path / "not_a_model.eqx"), "--data", str(record)], "not_a_model.eqx"),
    ]
    fj.save_model(tmp_path / "load.eqx", fj.NormalLoad(fj.Coulomb(Fc=1.0), reference=10.0))
    cases.append((["--model", str(tmp_path / "load.eqx"), "--data", str(record)], "load.eqx".removesuffix(".eqx")))
    for arguments, expected in cases:
        code = fj.main(["predict", *arguments, "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and expected in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


# compare's saved models run by `fricjax predict` reproduce compare's test scores (ensembles included): notebook 08's
# final cell checks it (to 1e-9) in the slow tier, where it runs anyway; on the damper it held to the printed digit.


@pytest.mark.slow  # a static-law fit on a damper record and its prediction of another (~30 s)
def test_predict_gives_a_saved_damper_model_the_nmse_compare_gave_it(data_dir, tmp_path, capsys):
    """Issue 55's acceptance on the real device: a model compare saved, run by `fricjax predict` on a record it was
    not fitted on, scores the NMSE compare printed for that record."""
    folder = data_dir / "damper" / "dataset-2" / "characterization_tests"
    train, other = folder / "0.25Hz36lbtension1amplitude.npz", folder / "0.5Hz36lbtension0.5amplitude.npz"
    out = tmp_path / "compare"
    argv = ["compare", "--data", str(train), "--test", str(other), "--models", "stribeck", "lugre", "--steps", "4"]
    assert fj.main([*argv, "--no-progress", "--out", str(out)]) == 0
    compared = {
        m["name"]: m["test_scores"][str(other)]["nmse"] for m in json.loads((out / "report.json").read_text())["models"]
    }
    models = [str(out / "models" / f"{name}.eqx") for name in ("stribeck", "lugre")]
    assert fj.main(["predict", "--model", *models, "--data", str(other), "--out", str(tmp_path / "predict")]) == 0
    report = json.loads((tmp_path / "predict" / "report.json").read_text())
    predicted = {score["model"]: score["nmse"] for score in report["scores"]}
    for name in ("stribeck", "lugre"):
        assert predicted[name] == pytest.approx(compared[name], rel=1e-9), (name, predicted, compared)
    capsys.readouterr()
