"""flexarm_ros: a ROS 2 digital twin of flexible-link robot arms.

``import flexarm_ros as fx``: ``fx.load_scene``, ``fx.simulate``, ``fx.linearize``,
``fx.modes``, ``fx.design``, ``fx.estimate``, ``fx.urdf``, ``fx.read_bag`` run what the
commands run
(:mod:`flexarm_ros.api`, docs/python.md).

The physics core (:mod:`flexarm_ros.model`) never imports rclpy; ROS nodes live in
:mod:`flexarm_ros.nodes` and are thin adapters over it.
"""

from flexarm_ros.version import __version__  # noqa: F401  (the package's version)

#: the Python API (:mod:`flexarm_ros.api`), imported on first use so that ``import
#: flexarm_ros`` stays as light as the commands need it
_API = ("load_scene", "simulate", "linearize", "modes", "design", "estimate", "read_bag",
        "urdf", "Result", "InputError", "SceneError")


def __getattr__(name):
    if name in _API:
        from flexarm_ros import api
        return getattr(api, name)
    raise AttributeError(f"module 'flexarm_ros' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_API))
