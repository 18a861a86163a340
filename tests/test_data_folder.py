"""`fj.data_folder()`: `$FRICJAX_DATA`, else `shared/data` beside the checkout; never the current folder."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import sys

import pytest

import fricjax as fj

ROOT = pathlib.Path(__file__).resolve().parents[1]
CHECKOUT_DATA = ROOT.parent / "shared" / "data"


def test_the_environment_variable_comes_first(tmp_path, monkeypatch):
    (tmp_path / "emps").mkdir()
    monkeypatch.setenv("FRICJAX_DATA", str(tmp_path))
    assert fj.data_folder() == tmp_path.resolve()
    assert fj.data_folder("emps") == tmp_path.resolve() / "emps"
    with pytest.raises(FileNotFoundError, match="no folder 'boucwen'"):
        fj.data_folder("boucwen")
    monkeypatch.setenv("FRICJAX_DATA", str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError, match="FRICJAX_DATA=.*nowhere.* names no folder"):
        fj.data_folder()


def test_without_the_variable_the_checkout_data_whatever_the_current_folder(tmp_path, monkeypatch):
    if not CHECKOUT_DATA.is_dir():
        pytest.skip(f"no shared/data beside this checkout ({CHECKOUT_DATA})")
    monkeypatch.delenv("FRICJAX_DATA", raising=False)
    for folder in (tmp_path, ROOT, ROOT / "src"):
        monkeypatch.chdir(folder)
        assert fj.data_folder() == CHECKOUT_DATA.resolve()


@pytest.mark.slow  # a fresh interpreter importing a copy of the package: about 4 s
def test_without_the_variable_nor_checkout_data_the_error_names_both(tmp_path):
    checkout = tmp_path / "checkout"
    shutil.copytree(
        ROOT / "src" / "fricjax", checkout / "src" / "fricjax", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copy(ROOT / "pyproject.toml", checkout / "pyproject.toml")
    env = {key: value for key, value in os.environ.items() if key != "FRICJAX_DATA"}
    env["PYTHONPATH"] = str(checkout / "src")
    code = "import fricjax as fj\ntry:\n    fj.data_folder()\nexcept FileNotFoundError as err:\n    print(err)"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True, check=True
    )
    message = out.stdout.strip()
    assert "FRICJAX_DATA is not set" in message and str(tmp_path / "shared" / "data") in message, message
