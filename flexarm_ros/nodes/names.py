"""ROS 2 names checked before rclpy starts (importable without rclpy): a bad
``--namespace`` is one line and exit 2, not an rclpy traceback from inside a node."""

from __future__ import annotations

import re

from flexarm_ros.errors import InputError

#: an absolute ROS 2 namespace (rmw_validate_namespace): tokens of letters, digits and
#: underscores that do not start with a digit, separated by single slashes, no trailing
#: slash; "/" alone is the root namespace
NAMESPACE = re.compile(r"/|(/[A-Za-z_][A-Za-z0-9_]*)+")
#: rmw's limit on a fully qualified name is 255 characters; the namespace leaves room for
#: the twin's topic names under it
NAMESPACE_MAX_LENGTH = 200


def check_namespace(flag: str, value: str | None) -> str | None:
    """``value`` as an absolute namespace (``flexarm`` → ``/flexarm``; "" is refused, the
    root is "/"), or InputError naming ``flag``, the value and the rule."""
    if value is None:
        return None
    ns = value if value.startswith("/") else "/" + value
    if not value or not NAMESPACE.fullmatch(ns) or len(ns) > NAMESPACE_MAX_LENGTH:
        raise InputError(f"{flag}: got {value!r}, expected a ROS 2 namespace: '/' or "
                         f"/-separated names of letters, digits and underscores that do not "
                         f"start with a digit, no empty or trailing parts, at most "
                         f"{NAMESPACE_MAX_LENGTH} characters (e.g. /flexarm or /lab/arm2)")
    return ns
