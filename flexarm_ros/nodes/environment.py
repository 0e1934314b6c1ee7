"""The ROS 2 environment of the twin's processes, set in one place.

* Every process that may start DDS (the ``flexarm`` command, each node's ``main()``, the
  graph of ``flexarm run``) keeps discovery on the loopback interface:
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the user set the variable
  (:func:`use_loopback`). No traffic leaves the machine by default.
* A graph that ``flexarm run`` starts, and the tools and tests that start graphs of their
  own, also get a private ``ROS_DOMAIN_ID`` unless the user set one (:func:`private_graph`):
  1 + pid mod 101, a valid domain on every platform, so concurrent runs on one machine do
  not hear each other. Child processes inherit it (:func:`child_environment`).
* A node started alone (``ros2 run flexarm_ros simulator``) keeps the user's domain (or
  ROS's default 0): the nodes of one graph started by hand must find each other.

Values the user set are never changed. This module only reads and writes environment
variables: it imports nothing from ROS, so the command line and the physics core can use it
without rclpy installed.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

DISCOVERY = "ROS_AUTOMATIC_DISCOVERY_RANGE"
DOMAIN = "ROS_DOMAIN_ID"
LOOPBACK = "LOCALHOST"
#: private domain ids are 1 + pid mod DOMAINS (1..101: the ids whose DDS ports are valid on
#: Linux, macOS and Windows)
DOMAINS = 101


def use_loopback(env: MutableMapping | None = None) -> None:
    """Set ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` in ``env`` (default ``os.environ``)
    unless it is set."""
    env = os.environ if env is None else env
    env.setdefault(DISCOVERY, LOOPBACK)


def private_graph(env: MutableMapping | None = None, pid: int | None = None) -> dict:
    """Loopback discovery and a private ``ROS_DOMAIN_ID`` (1 + ``pid`` mod 101, ``pid``
    default this process's id), each unless set, in ``env`` (default ``os.environ``).
    Returns ``{variable: value}`` of both."""
    env = os.environ if env is None else env
    use_loopback(env)
    env.setdefault(DOMAIN, str(1 + (os.getpid() if pid is None else pid) % DOMAINS))
    return {DISCOVERY: env[DISCOVERY], DOMAIN: env[DOMAIN]}


def child_environment() -> dict:
    """A copy of ``os.environ`` for a child process of this process's private graph
    (:func:`private_graph` applied to this process first, so parent and children agree)."""
    private_graph()
    return dict(os.environ)


def domain_id(env: MutableMapping | None = None) -> int:
    """The ROS domain id in ``env`` (default ``os.environ``; 0, ROS's default, when unset).
    Raises ValueError naming the variable when it is not an integer in 0..232."""
    env = os.environ if env is None else env
    text = env.get(DOMAIN, "").strip() or "0"
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 232:
        raise ValueError(f"{DOMAIN}: got {text!r}, expected an integer 0..232 (0..101 on "
                         f"Linux)")
    return value
