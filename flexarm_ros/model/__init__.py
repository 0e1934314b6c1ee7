"""The equations of the flexible chain (no rclpy). Its public API for the layers that
draw or analyse a recorded run without simulating it (``flexarm_ros.viz``) is what this
package exports: :class:`~flexarm_ros.model.chain.Chain` (kinematics, centerlines of a
coordinate vector). Imported on first use, so importing a model submodule stays cheap.
"""

__all__ = ["Chain"]


def __getattr__(name):
    if name == "Chain":
        from flexarm_ros.model.chain import Chain
        return Chain
    raise AttributeError(f"module 'flexarm_ros.model' has no attribute {name!r}")
