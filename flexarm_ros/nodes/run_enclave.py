"""Which run a node belongs to: the enclave of a run's nodes (:func:`new_run_enclave`:
when it started and by which process), and another twin in a node's namespace and domain
(:func:`other_twin`; docs/decisions/0027-one-twin-per-namespace-and-domain.md)."""

from __future__ import annotations

import os
import time

#: the enclave of a run's nodes: this prefix and a random token (run/graphs.py, new_run_enclave)
RUN_ENCLAVE_PREFIX = "/flexarm_run_"
#: the names of the twin's nodes
TWIN_NODES = ("simulator", "motor_driver", "controller", "recorder")


def new_run_enclave() -> str:
    """A fresh enclave for the nodes of one run: the prefix, the run's start in ms of
    wall time (which of two runs came first), the pid of the process that started it
    (whether it still runs) and a random token."""
    import secrets
    return (f"{RUN_ENCLAVE_PREFIX}{int(time.time() * 1000)}_{os.getpid()}_"
            f"{secrets.token_hex(3)}")


def _started_ms(enclave: str) -> int:
    """The start time a run enclave carries (0 for one without)."""
    try:
        return int(enclave[len(RUN_ENCLAVE_PREFIX):].split("_")[0])
    except ValueError:
        return 0


def _running(enclave: str) -> bool:
    """Whether the run of ``enclave`` still runs: the process that started it is alive
    (discovery is loopback-only, so it is on this machine). A run killed outright leaves
    its nodes on the graph until their DDS lease ends (~20 s); they are not a twin."""
    try:
        pid = int(enclave[len(RUN_ENCLAVE_PREFIX):].split("_")[1])
    except (ValueError, IndexError):
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def other_twin(node, older_only: bool = False) -> str | None:
    """What the graph shows of another twin in ``node``'s namespace on its domain, else
    None: a twin's node there in another run's enclave (``run_enclave``), or a second node
    named ``simulator`` (twins started by hand). Two twins there would take each other's
    messages — their topics and node names are the same, and neither a user's node nor
    RViz could tell them apart — so a node does not start beside another twin, and a
    running simulator stops its run when it finds a twin that started before it
    (``older_only``: it slipped past its start condition before discovery showed the
    other; docs/decisions/0027-one-twin-per-namespace-and-domain.md)."""
    ns = node.get_namespace()
    mine = getattr(node, "p", {}).get("run_enclave", "")
    here = [(name, enc) for name, nns, enc in node.get_node_names_and_namespaces_with_enclaves()
            if nns == ns and name in TWIN_NODES]
    others = sorted({enc for _, enc in here if mine and enc != mine
                     and enc.startswith(RUN_ENCLAVE_PREFIX) and _running(enc)
                     and not (older_only and (_started_ms(enc), enc) > (_started_ms(mine),
                                                                          mine))})
    # nodes started by hand (no run enclave): a second simulator is the only sign
    sims = 0 if mine else sum(1 for name, _ in here if name == "simulator")
    if not others and sims <= 1:
        return None
    what = (", ".join(f"{sorted(n for n, e in here if e == enc)} of the run in enclave {enc}"
                      for enc in others) if others else f"{sims} nodes named simulator")
    return (f"another twin runs in namespace {ns} on ROS_DOMAIN_ID "
            f"{node.context.get_domain_id()} ({what}): two twins there take each other's "
            f"messages; give one of them another --namespace or ROS_DOMAIN_ID")
