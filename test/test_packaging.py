"""The ament_python layout builds with colcon and installs what `ros2 run` executes; a pip
wheel puts only the ``flexarm*`` names on PATH."""

import pytest
import configparser
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NODES = ("simulator", "motor_driver", "controller", "recorder", "estimator")
PIP_SCRIPTS = {"flexarm", "flexarm-simulator", "flexarm-motor-driver", "flexarm-controller",
               "flexarm-recorder", "flexarm-estimator"}


def _copy_tree(dest):
    """The tracked files of the checkout (what a clone has) under ``dest``."""
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    for f in files:
        if (ROOT / f).is_file():
            (dest / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / f, dest / f)


def _colcon():
    exe = Path(sys.executable).with_name("colcon")
    return str(exe) if exe.exists() else shutil.which("colcon")


@pytest.mark.heavy
@pytest.mark.subprocess
def test_colcon_build_installs_the_executable_and_scenes(tmp_path):
    colcon = _colcon()
    assert colcon, "colcon is part of the [dev] extra: pip install -e .[dev]"
    src = tmp_path / "src" / "flexarm_ros"
    _copy_tree(src)
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    r = subprocess.run([colcon, "build", "--base-paths", "src"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    prefix = tmp_path / "install" / "flexarm_ros"
    exe = prefix / "lib" / "flexarm_ros" / "flexarm"
    assert exe.exists()
    assert (prefix / "share" / "flexarm_ros" / "config" / "two_link_free.yaml").exists()
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" /
            "flexarm_ros").exists()
    site = next(prefix.glob("lib/python3*/site-packages"))
    env = dict(os.environ, PYTHONPATH=str(site), AMENT_PREFIX_PATH=str(prefix))
    r = subprocess.run([sys.executable, str(exe), "simulate", "link", "--duration", "0.01",
                        "--quiet", "--json"], env=env, capture_output=True, text=True,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert '"status": 0' in r.stdout
    # `ros2 run flexarm_ros <node>` executes lib/flexarm_ros/<node>
    for node in NODES:
        assert (prefix / "lib" / "flexarm_ros" / node).exists(), node
    r = subprocess.run([sys.executable, str(prefix / "lib" / "flexarm_ros" / "simulator"),
                        "--help"], env=env, capture_output=True, text=True, cwd=tmp_path,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("usage: simulator") and "  rung (default" in r.stdout


@pytest.mark.subprocess
def test_pip_metadata_puts_only_the_flexarm_names_on_path(tmp_path):
    """``pip install .`` / ``pip install -e .`` install a wheel whose entry points
    setuptools' ``egg_info`` step writes (the PEP 517 hooks run it before bdist_wheel /
    editable_wheel): the ``flexarm*`` names only, no plain ``simulator`` or ``controller``
    on PATH."""
    src = tmp_path / "src"
    _copy_tree(src)
    meta = tmp_path / "meta"
    meta.mkdir()
    r = subprocess.run([sys.executable, "setup.py", "egg_info", "--egg-base", str(meta)],
                       cwd=src, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    cfg = configparser.ConfigParser()
    cfg.read(meta / "flexarm_ros.egg-info" / "entry_points.txt")
    assert set(cfg["console_scripts"]) == PIP_SCRIPTS
