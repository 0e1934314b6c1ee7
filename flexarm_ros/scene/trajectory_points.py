"""The check of a trajectory's points before it changes anything — a scene's move program
(``control.moves``) as it loads, a ``trajectory_msgs/JointTrajectory`` as it arrives
(:mod:`flexarm_ros.control.trajectory` follows them): names that are the scene's joints
(each once, any order), finite positions and velocities of the right length, times
strictly increasing and > 0, targets within the joints' position limits."""

from __future__ import annotations

import numpy as np

#: the most points a trajectory may carry (a message or a move program)
MAX_POINTS = 10_000
#: the field names the messages use: a JointTrajectory's (a move program passes its own)
MESSAGE_FIELDS = {"points": "points", "positions": "positions", "velocities": "velocities",
                  "time_from_start": "time_from_start"}


def beyond_limits(P, limits):
    """(point, joint, lo, hi) of the first target of ``P`` (k, n) outside its joint's
    (lo, hi) in ``limits`` (None: no limit), or None."""
    for j, lim in enumerate(limits):
        if lim is None:
            continue
        lo, hi = lim
        bad = np.nonzero((P[:, j] < lo) | (P[:, j] > hi))[0]
        if len(bad):
            return int(bad[0]), j, lo, hi
    return None


def check_points(expected_names, names, times, positions, velocities, limits,
                 fields=MESSAGE_FIELDS):
    """(the permutation into the scene's joint order, positions (k, n), velocities (k, n)
    or None), or ValueError naming what is wrong in the words of ``fields`` (the message's
    field names by default). ``limits``: per joint (lo, hi) rad or None."""
    pts, pos, vel = fields["points"], fields["positions"], fields["velocities"]
    expected = list(expected_names)
    names = list(names)
    n = len(expected)
    unknown = [x for x in names if x not in expected]
    if unknown:
        raise ValueError(f"joint_names: got {unknown[0]!r}, expected the scene's joints "
                         f"{', '.join(expected)}")
    if len(names) != n or len(set(names)) != n:
        raise ValueError(f"joint_names: got {names}, expected each of "
                         f"{', '.join(expected)} once")
    order = [names.index(x) for x in expected]
    k = len(times)
    if k == 0:
        raise ValueError(f"{pts}: got none, expected at least one point")
    if k > MAX_POINTS:
        raise ValueError(f"{pts}: got {k}, expected at most {MAX_POINTS}")
    t = np.asarray(times, float)
    if not np.all(np.isfinite(t)) or t[0] <= 0.0 or np.any(np.diff(t) <= 0.0):
        raise ValueError(f"{fields['time_from_start']}: got {t[:6].tolist()}, expected "
                         f"finite times "
                         f"> 0 s, strictly increasing")
    P = np.full((k, n), np.nan)
    for i, p in enumerate(positions):
        p = list(p)
        if len(p) != n:
            raise ValueError(f"{pts}[{i}].{pos}: got {len(p)} values, expected {n}")
        P[i] = np.asarray(p, float)[order]
    if not np.all(np.isfinite(P)):
        i = int(np.nonzero(~np.all(np.isfinite(P), axis=1))[0][0])
        raise ValueError(f"{pts}[{i}].{pos}: got a non-finite value, expected finite "
                         f"angles (rad)")
    V = None
    given = [len(list(v)) for v in velocities] if velocities is not None else []
    if any(given):
        if any(g != n for g in given):
            i = next(i for i, g in enumerate(given) if g != n)
            raise ValueError(f"{pts}[{i}].{vel}: got {given[i]} values, expected "
                             f"{n} on every point or none")
        V = np.array([np.asarray(list(v), float)[order] for v in velocities])
        if not np.all(np.isfinite(V)):
            raise ValueError(f"{pts}.{vel}: got a non-finite value, expected finite "
                             "rates (rad/s)")
    out = beyond_limits(P, limits)
    if out is not None:
        i, j, lo, hi = out
        raise ValueError(f"{pts}[{i}].{pos}: got {P[i, j]:.6g} rad for {expected[j]}, "
                         f"expected within its position limits [{lo:g}, {hi:g}] rad")
    return order, P, V
