"""ament_python package flexarm_ros (also a plain pip package: `pip install -e .[dev]`)."""

from glob import glob

from setuptools import find_packages, setup

package_name = "flexarm_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", sorted(glob("config/*.yaml"))),
    ],
    python_requires=">=3.10",
    install_requires=["numpy>=1.24", "scipy>=1.10", "PyYAML>=6", "matplotlib>=3.6", "mcap>=1.1",
                      "mcap-ros2-support>=0.5"],
    extras_require={
        "ros": ["ros-rclpy", "ros-std-msgs", "ros-sensor-msgs", "ros-geometry-msgs",
                "ros-rmw-fastrtps-cpp"],
        "fast": ["numba>=0.60"],
        "viz": ["rerun-sdk>=0.20"],
        "dev": ["pytest>=7", "hypothesis>=6", "rosbags>=0.9", "colcon-common-extensions", "colcon-ros",
                "ros-ament-package"],
    },
    zip_safe=True,
    maintainer="flexarm_ros developers",
    maintainer_email="dev@flexarm.invalid",
    description="ROS 2 digital twin of flexible-link robot arms",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "flexarm = flexarm_ros.cli:main",
            # the twin's nodes: `ros2 run flexarm_ros simulator` runs lib/flexarm_ros/simulator
            "simulator = flexarm_ros.nodes.simulator:main",
            "motor_driver = flexarm_ros.nodes.motor_driver:main",
            "controller = flexarm_ros.nodes.controller:main",
            "recorder = flexarm_ros.nodes.recorder:main",
            "flexarm-simulator = flexarm_ros.nodes.simulator:main",
            "flexarm-motor-driver = flexarm_ros.nodes.motor_driver:main",
            "flexarm-controller = flexarm_ros.nodes.controller:main",
            "flexarm-recorder = flexarm_ros.nodes.recorder:main",
        ],
    },
)
