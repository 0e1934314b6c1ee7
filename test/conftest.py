"""Suite-wide settings: DDS on loopback and a private ROS domain per test run."""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 90))


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long studies (CI runs -m 'not slow')")
