"""The package version (one place: ``flexarm_ros.__version__`` is this; modules below the
package's ``__init__`` that the Python API imports read it here, without importing the
package root and its API)."""

__version__ = "0.2.0"
