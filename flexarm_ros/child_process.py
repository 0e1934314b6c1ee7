"""The command line of a child process that runs one of the package's modules
(:func:`python_module`): the recorder's writer process (:mod:`flexarm_ros.bag.writer_process`)
and the nodes ``flexarm run`` starts (:mod:`flexarm_ros.run`). Standard library only."""

from __future__ import annotations

import sys

#: ``python -c`` bootstrap of :func:`python_module` before Python 3.11 (no ``-P``): drop the
#: working directory from sys.path, then run the module as ``-m`` would
_SAFE_RUN = ("import runpy, sys; sys.path[:] = [p for p in sys.path if p not in ('', '.')]; "
             "m = sys.argv.pop(1); sys.argv[0] = m; "
             "runpy.run_module(m, run_name='__main__', alter_sys=True)")


def python_module(module: str, safe_path_flag: bool | None = None) -> list:
    """The command line of a child process that runs ``python -m module`` (this
    interpreter) importing the package from where this process did, never from the
    child's working directory. ``python -m`` puts the working directory first on
    sys.path: a folder named ``flexarm_ros`` there — the directory that holds a clone —
    would shadow the installed package and every child would fail on import (met by a
    new user running ``flexarm run`` next to their clone). Python ≥ 3.11: ``-P``; before
    it a bootstrap that drops the working directory first (``safe_path_flag``: force one
    or the other; None: by version). ``PYTHONPATH`` keeps working either way (a ROS
    install needs it), unlike ``-I``."""
    if safe_path_flag is None:
        safe_path_flag = sys.version_info >= (3, 11)
    if safe_path_flag:
        return [sys.executable, "-P", "-m", module]
    return [sys.executable, "-c", _SAFE_RUN, module]
