"""ament_python package flexarm_ros (also a plain pip package: `pip install -e .[dev]`).

Executables: pip puts ``flexarm`` and ``flexarm-simulator``, ``flexarm-motor-driver``,
``flexarm-controller``, ``flexarm-recorder``, ``flexarm-estimator`` on PATH. colcon / ament (which run
``setup.py install`` or ``setup.py develop``; setup.cfg sends their scripts to
``lib/flexarm_ros``) also install the nodes under their plain names, what ``ros2 run
flexarm_ros simulator`` executes; a pip wheel never does, since ``simulator`` or
``controller`` on PATH would clash with other programs.
"""

import sys
from glob import glob

from setuptools import find_packages, setup

package_name = "flexarm_ros"

NODES = ("simulator", "motor_driver", "controller", "recorder", "estimator")
# setup.py run directly by colcon/ament (pip builds wheels: bdist_wheel, editable_wheel)
ROS_INSTALL = bool({"install", "develop"} & set(sys.argv[1:]))
scripts = ["flexarm = flexarm_ros.cli:main"]
scripts += [f"flexarm-{n.replace('_', '-')} = flexarm_ros.nodes.{n}:main" for n in NODES]
if ROS_INSTALL:
    scripts += [f"{n} = flexarm_ros.nodes.{n}:main" for n in NODES]

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", sorted(glob("config/*.yaml"))),
    ],
    python_requires=">=3.10",
    install_requires=["numpy>=1.24", "scipy>=1.10", "PyYAML>=6", "matplotlib>=3.6", "mcap>=1.1",
                      "mcap-ros2-support>=0.5",
                      # one BLAS thread around the linear analyses of rung auto,
                      # --estimate and the trapezoid's tolerance (small matrices: the
                      # threads only wait on each other, 1.6x measured)
                      "threadpoolctl>=3.1"],
    extras_require={
        "ros": ["ros-rclpy", "ros-std-msgs", "ros-sensor-msgs", "ros-geometry-msgs",
                "ros-visualization-msgs", "ros-trajectory-msgs", "ros-diagnostic-msgs",
                "ros-rmw-fastrtps-cpp"],
        "fast": ["numba>=0.60"],
        "viz": ["rerun-sdk>=0.20"],
        # bench/bench_peers.py only, never imported at run time: Exudyn's ANCF cable and
        # MuJoCo's elastic rod against the rod rung (docs/accuracy.md, "Against peer codes")
        "peers": ["exudyn>=1.9", "mujoco>=4.0"],   # tested: exudyn 1.13.6, mujoco 4.0.0 (its flexcomp rod)
        # ensembles (flexarm sweep / uncertainty / sensitivity): Dask local or remote
        # clusters, SALib's Morris and Sobol, the Dask dashboard, Parquet tables
        "ensemble": ["dask>=2024.8", "distributed>=2024.8", "SALib>=1.5", "bokeh>=3.1",
                     "pyarrow>=14"],
        # the suite runs on pytest-xdist workers (pytest.ini: -n auto, one ROS domain per
        # worker) with a per-test time limit (pytest-timeout) so a hang fails, not stalls
        # python-control: fx.linearize returns its StateSpace where it is installed (the
        # tests check it against the export)
        "dev": ["pytest>=7", "pytest-xdist>=3.5", "pytest-timeout>=2.2", "hypothesis>=6",
                "control>=0.10",
                "rosbags>=0.9", "colcon-common-extensions", "colcon-ros", "ros-ament-package"],
    },
    zip_safe=True,
    maintainer="flexarm_ros developers",
    maintainer_email="dev@flexarm.invalid",
    description="ROS 2 digital twin of flexible-link robot arms",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": scripts},
)
