"""The ament_python layout builds with colcon and installs what `ros2 run` executes."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _colcon():
    exe = Path(sys.executable).with_name("colcon")
    return str(exe) if exe.exists() else shutil.which("colcon")


def test_colcon_build_installs_the_executable_and_scenes(tmp_path):
    colcon = _colcon()
    assert colcon, "colcon is part of the [dev] extra: pip install -e .[dev]"
    src = tmp_path / "src" / "flexarm_ros"
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    for f in files:
        (src / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, src / f)
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
