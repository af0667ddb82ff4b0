"""The wheel is the product: built from the repository it carries every package and every shipped config,
and installed on its own it runs a shipped scenario by short name from a folder that is not the source."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from drivers.resources import SHIPPED, find, shipped
from tests.helpers import ROOT

CODE = ("hil", "drivers", "plant", "safety", "controller")


def test_every_package_and_config_is_listed_for_the_wheel():
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for root in CODE
        for p in (ROOT / root).rglob("__init__.py")
    }
    assert on_disk | {"pure_hil_configs"} == set(setuptools["packages"])
    patterns = setuptools["package-data"]["pure_hil_configs"]
    suffixes = {p.suffix for p in (ROOT / "configs").rglob("*.*") if p.suffix != ".py"}
    assert {f"**/*{s}" for s in suffixes} <= set(patterns)


def test_short_names_and_source_paths_mean_the_same_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not the source tree
    assert find("balance", "scenarios") == SHIPPED / "scenarios/balance.toml"
    assert find("configs/riders/s07_abi_73kg_176.toml") == find("s07_abi_73kg_176", "riders")
    assert "speed_limiting" in shipped("scenarios") and "pure" in shipped("robot")
    (tmp_path / "balance").mkdir()
    (tmp_path / "mine.toml").write_text("")
    assert find("mine.toml", "scenarios") == Path("mine.toml")  # a file here wins over a shipped name
    with pytest.raises(ValueError, match="shipped scenarios: balance, bench_smoke"):
        find("no_such_scenario", "scenarios")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    # From a copy: setuptools builds in the source folder (build/) and would leave it behind.
    source = out / "source"
    skip = (".git", ".venv", "runs", "build", "dist", "*.egg-info", "__pycache__", ".*_cache", ".hypothesis")
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(*skip))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    env = {k: v for k, v in os.environ.items() if k != "PURE_HIL_MYPYC"}  # the default build
    command = [*pip, "wheel", "--no-deps", "-w", str(out), str(source)]
    subprocess.run(command, check=True, timeout=300, env=env)
    return next(out.glob("pure_hil-*.whl"))


def test_the_wheel_holds_the_code_and_every_shipped_config(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for path in (ROOT / "configs").rglob("*.*"):
        if path.suffix != ".py":
            assert f"pure_hil_configs/{path.relative_to(ROOT / 'configs')}" in names
    assert {"hil/cli.py", "hil/faults/__init__.py", "controller/embedded.py", "drivers/resources.py"} <= names
    page = {f"hil/console/static/{name}" for name in ("index.html", "console.js", "console.css")}
    assert page <= names, "the console's page ships in the wheel"
    # The default build is pure Python (the compiled one is asked for: PURE_HIL_MYPYC=1, setup.py).
    assert wheel.name.endswith("-py3-none-any.whl") and not [n for n in names if n.endswith(".so")]


def test_the_installed_wheel_runs_a_shipped_scenario_by_short_name_from_another_folder(wheel, tmp_path):
    site = tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "install", "--no-deps", "--target", str(site), str(wheel)], check=True, timeout=300)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "OPENBLAS_NUM_THREADS": "1"}
    where = subprocess.run(
        [sys.executable, "-c", "import hil, drivers.resources as r; print(hil.__file__); print(r.SHIPPED)"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert all(Path(p).is_relative_to(site) for p in where), where  # the wheel's copy, not the source tree
    run = subprocess.run(
        [sys.executable, "-m", "hil.cli", "run", "balance", "--out", "run", "--quiet"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "PASSED" in run.stdout and (work / "run/summary.json").is_file()
