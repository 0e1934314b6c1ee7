"""Suite-wide settings: DDS on loopback and a private ROS domain per test run."""

from flexarm_ros.nodes import environment

environment.private_graph()


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long studies (CI runs -m 'not slow')")
