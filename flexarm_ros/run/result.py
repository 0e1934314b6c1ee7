"""What a run of the twin's graph came to: :class:`RunResult`, its one-line summary and
its JSON (``flexarm run --json``), filled from the simulator's summary
(:func:`take_summary`, :func:`read_summary`), the finalized bag (:func:`bag_counts`,
:func:`bag_rejections`, :func:`bag_first_command_s`) and the CPU sampled over the ticking
(:func:`cpu_sampler`, :func:`take_cpu`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from flexarm_ros.run.graphs import NODES

@dataclass
class RunResult:
    scene: str
    mode: str
    processes: bool
    record: Path | None
    wall_s: float
    sim_s: float | None = None              # in-process runs only
    ticks: int | None = None
    real_time_factor: float | None = None
    overruns: int | None = None
    rejected_commands: int | None = None     # on both command topics
    rejected: dict | None = None              # topic -> {reason: count}, every node input
    extra_commands: int | None = None         # lockstep, driver in this process: beyond 1/state
    diverged: str | None = None               # the divergence message (exit status 3)
    stalled: str | None = None                # lockstep ended without answers (status 3)
    interrupted: bool = False
    signal: str | None = None                 # what interrupted the run (SIGINT, SIGTERM)
    ended_early: dict | None = None           # node -> how it ended before the run did
    end_s: float | None = None                # the simulated time the run was to reach
    missing: dict | None = None               # topic -> published, recorded: bag short
    conflict: str | None = None               # another twin in the namespace (status 3)
    twin_seen: str | None = None              # a newer twin appeared and stopped itself
    returncodes: dict = field(default_factory=dict)
    recovered: str | None = None            # what recover_killed_bag() did, if anything
    nodes: tuple = ()                         # the nodes that ran
    pacing: dict | None = None                # realtime: the simulator's Pacer.summary()
    published: dict | None = None             # simulator: messages per absolute topic
    recorded: dict | None = None              # the bag's message count per topic
    cpus: dict | None = None                  # --processes with pinning: node -> CPUs
    first_command_s: float | None = None      # sim time of the first recorded command
    layout: str = ""                          # "one", "split" or "processes"
    integrator: str | None = None             # what the plant stepped with (rk4, rkn4)
    step_s: float | None = None               # ... and its step
    cpu: dict | None = None                   # twin/cpu_load.cpu_budget over the ticking
    kept_previous: bool = False               # no tick: the bag already at `record` kept
    sets: dict = field(default_factory=dict)  # --set: {key path: value} every node applied

    @property
    def ticking_s(self) -> float | None:
        """Wall time of the ticking alone (what the real-time factor divides by); the
        rest of ``wall_s`` is start-up (processes, imports, discovery) and the end."""
        rtf = self.real_time_factor
        return self.sim_s / rtf if self.sim_s is not None and rtf else None

    def to_json(self) -> dict:
        """The summary as JSON-ready numbers (``flexarm run --json``)."""
        p = self.pacing or {}
        return {"scene": self.scene, "set": dict(self.sets), "mode": self.mode,
                "processes": self.processes,
                "layout": self.layout or ("processes" if self.processes else "one"),
                "nodes": list(self.nodes), "record": str(self.record) if self.record else None,
                "wall_time_s": self.wall_s, "ticking_wall_time_s": self.ticking_s,
                "sim_time_s": self.sim_s, "ticks": self.ticks,
                "integrator": self.integrator, "step_s": self.step_s,
                "real_time_factor": self.real_time_factor,
                "first_command_s": self.first_command_s,
                "late_ticks": p.get("late_ticks"),
                "lateness_p50_s": p.get("lateness_p50_s"),
                "lateness_p99_s": p.get("lateness_p99_s"),
                "lateness_max_s": p.get("lateness_max_s"),
                "late_policy": p.get("late_policy"), "skipped_ticks": p.get("skipped_ticks"),
                "scheduling": p.get("scheduling"),
                "slowed_s": p.get("slowed_s"),
                "effort_waits": p.get("effort_waits"),
                "effort_wait_timeouts": p.get("effort_wait_timeouts"),
                "published": self.published, "recorded": self.recorded,
                "rejected_commands": (self.rejected_commands if self.rejected_commands
                                      is not None else
                                      (sum(sum(by.values()) for by in self.rejected.values())
                                       if self.rejected is not None else None)),
                "rejected": self.rejected, "extra_commands": self.extra_commands,
                "record_kept_previous": self.kept_previous,
                "diverged": self.diverged,
                "stalled": self.stalled,
                "interrupted": self.interrupted, "signal": self.signal,
                "end_s": self.end_s, "ended_early": self.ended_early,
                "missing": self.missing, "conflict": self.conflict,
                "twin_seen": self.twin_seen,
                "returncodes": self.returncodes,
                "recovered": self.recovered,
                "cpus": ({n: sorted(c) for n, c in self.cpus.items()} if self.cpus
                         else None),
                **(self.cpu or {"cpu_ms_per_tick": None, "cpu_ms_per_tick_total": None,
                                "cpu_share": None, "cpus_available": None})}

    def summary(self) -> str:
        from flexarm_ros.twin.pacing import short_scheduling
        how = ("one process per node" if self.processes else
               "the simulator in a process of its own" if self.layout == "split" else
               "one process")
        s = f"{self.scene}: {self.mode} run ({how}"
        left = [n for n in NODES if self.nodes and n not in self.nodes]
        s += f"; without {', '.join(left)})" if left else ")"
        if self.sim_s is not None:
            tick = self.ticking_s
            s += (f", {self.sim_s:.3f} s simulated in "
                  + (f"{tick:.3g} s of ticking, {self.wall_s:.3g} s with start-up "
                     if tick is not None else f"{self.wall_s:.3g} s ")
                  + f"(real-time factor {self.real_time_factor:.3g}")
            p = self.pacing
            s += (f", {p['late_ticks']} of {p['ticks']} ticks late, lateness p99 "
                  f"{p['lateness_p99_s'] * 1e3:.3g} ms" + (
                      f"; pacing thread {short_scheduling(p['scheduling'])}"
                      if p.get("scheduling") else "") + ")" if p else ")")
        else:
            s += f", {self.wall_s:.3g} s wall"
        if self.cpu and self.cpu["cpu_ms_per_tick"]:
            c = self.cpu
            s += ("; CPU per tick " + ", ".join(
                f"{k} {v:.2f}" for k, v in sorted(c["cpu_ms_per_tick"].items(),
                                                  key=lambda kv: -kv[1]))
                  + f" ms ({100 * c['cpu_share']:.0f} % of {c['cpus_available']} CPUs)")
            p = self.pacing
            if p and p["ticks"] and p["late_ticks"] > 0.01 * p["ticks"]:
                s += _busy_hint(c, 1e3 * self.sim_s / self.ticks,
                                self.layout or ("processes" if self.processes else "one"))
        if self.first_command_s is not None and self.first_command_s > 0:
            s += (f"; the first command came at {self.first_command_s:.3f} s (the drives "
                  f"held 0 before it)")
        if self.interrupted:
            s += f", interrupted by {self.signal}" if self.signal else ", interrupted"
        if self.ended_early:
            s += "; " + "; ".join(f"{n} {how}" for n, how in self.ended_early.items())
        if self.diverged:
            s += ", diverged"
        if self.stalled:
            s += ", stalled"
        if self.conflict:
            s += ", stopped: another twin in its namespace and domain"
        if self.twin_seen:
            s += f"; {self.twin_seen}"
        if self.extra_commands:
            s += (f"; {self.extra_commands} command(s) beyond one per state (lockstep: the "
                  f"pairing shifted from the first on)")
        if self.rejected:
            s += "; rejected: " + "; ".join(
                f"{t} {sum(by.values())} (" + ", ".join(f"{n} {r}" for r, n in
                                                        sorted(by.items())) + ")"
                for t, by in sorted(self.rejected.items()))
        elif self.rejected is not None:
            s += "; no message rejected"
        if self.missing:
            s += "; MISSING from the bag: " + ", ".join(
                f"{t} {v['recorded']} of {v['published']}" for t, v in self.missing.items())
        if self.record and self.kept_previous:
            s += (f"; no tick recorded: {self.record} keeps the bag that was there (the "
                  f"empty one discarded)")
        elif self.record:
            s += f" → {self.record}"
        s += f" ({self.recovered})" if self.recovered else ""
        if self.sets:
            from flexarm_ros.scene.overrides import format_sets
            s += f"\n  set: {format_sets(self.sets)}"
        return s


def bag_rejections(path) -> dict | None:
    """The recorder's ``rejected_messages`` metadata of a finalized bag (None: none)."""
    import json

    from mcap.reader import make_reader
    try:
        with open(path, "rb") as f:
            for rec in make_reader(f).iter_metadata():
                if rec.name == "rejected_messages":
                    return json.loads(rec.metadata["by_topic"])
    except Exception:                         # a truncated bag has no summary: no counts
        return None
    return None


def bag_counts(path) -> dict | None:
    """Messages per topic in a finalized bag's summary (None: no summary)."""
    from mcap.reader import make_reader
    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:                         # a truncated bag has no summary
        return None
    if summary is None or summary.statistics is None:
        return None
    by_id = summary.statistics.channel_message_counts
    return {ch.topic: int(by_id.get(cid, 0)) for cid, ch in summary.channels.items()}


def bag_first_command_s(path) -> float | None:
    """Log time (sim s) of the first message on the motor driver's command topic of a
    finalized bag (None: no such message or no summary)."""
    from mcap.reader import make_reader

    from flexarm_ros.twin import topics as T
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                return None
            topics = [c.topic for c in summary.channels.values()
                      if c.topic.endswith("/" + T.COMMANDS)]
            for _, _, m in reader.iter_messages(topics=topics):
                return m.log_time * 1e-9
    except Exception:                         # a truncated bag: not known
        return None
    return None


def read_summary(path) -> dict | None:
    import json
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


#: the graph's share of the CPUs above which the summary says why ticks are late: with
#: the busiest CPU at load u a stall of the host of S seconds makes S/(T·(1 − u)) late
#: ticks of period T, four per stalled period at u = 0.75 (twin/cpu_load.py)
BUSY_SHARE = 0.75


def _busy_hint(cpu: dict, period_ms: float, layout: str) -> str:
    """Why a realtime run with late ticks had them, where its CPU budget says so: the
    graph took more than BUSY_SHARE of the CPUs, or one process more than BUSY_SHARE of
    a period per tick (a process's Python runs one thread at a time); "" otherwise."""
    busiest, ms = max(cpu["cpu_ms_per_tick"].items(), key=lambda kv: kv[1])
    if cpu["cpu_share"] > BUSY_SHARE:
        why = f"the graph takes {100 * cpu['cpu_share']:.0f} % of the CPUs"
    elif ms > BUSY_SHARE * period_ms:
        why = f"{busiest} takes {ms:.2f} ms of each {period_ms:.3g} ms tick"
    else:
        return ""
    fix = ("--layout one, " if layout == "processes" else "") + \
        "a lower control rate, a coarser model or more CPUs"
    return f" — {why}, so every stall of the host makes a run of late ticks: {fix}"


def cpu_sampler(root_role: str):
    from flexarm_ros.twin.cpu_load import CpuSampler
    return CpuSampler(root_role=root_role).start()


def take_cpu(res: RunResult, sampler, sim: dict | None, sim_role: str,
              cpus: int) -> None:
    """``res.cpu`` from the (stopped) ``sampler``'s readings over the simulator's ticking
    (its summary ``sim``), the simulator's own process taken exactly from its
    ``process_cpu_s`` (``sim_role``: the role its process has in the sampler); ``cpus``:
    how many the graph could run on (this process's affinity when the run began)."""
    from flexarm_ros.twin.cpu_load import cpu_budget
    span = (sim or {}).get("ticking_monotonic_s")
    if not span or not res.ticks or not sampler.samples:
        return
    cpu_s = sampler.between(*span)
    if sim.get("process_cpu_s") is not None:
        cpu_s[sim_role] = sim["process_cpu_s"]
    res.cpu = cpu_budget(cpu_s, res.ticks, span[1] - span[0], cpus)


def take_summary(res: RunResult, sim: dict, namespace: str) -> None:
    """Fill ``res`` from the simulator's :meth:`SimulatorNode.summary`; ``published`` under
    the topics' absolute names, as ``recorded``."""
    from flexarm_ros.twin.topics import resolve
    res.sim_s, res.ticks = sim["sim_time_s"], sim["ticks"]
    res.integrator, res.step_s = sim.get("integrator"), sim.get("step_s")
    res.real_time_factor = sim["real_time_factor"]
    res.published = {resolve(namespace, t): n for t, n in sim["published"].items()}
    res.diverged = res.diverged or sim.get("diverged")
    res.end_s = sim.get("end_s")
    if sim.get("stopped_by"):
        res.ended_early = {"simulator": f"stopped by {sim['stopped_by']} from outside the run "
                                        f"at t = {res.sim_s:.6g} s" + (
                                            f" of {res.end_s:.6g} s" if res.end_s else ""),
                           **{k: v for k, v in (res.ended_early or {}).items()
                              if k != "simulator"}}
    res.stalled = res.stalled or sim.get("stalled")
    res.conflict = res.conflict or sim.get("conflict")
    res.twin_seen = sim.get("twin_seen")
    if sim.get("mode") == "realtime":
        res.pacing = {k: sim[k] for k in ("ticks", "late_ticks", "lateness_p50_s",
                                          "lateness_p99_s", "lateness_max_s", "late_policy",
                                          "late_bound_s", "skipped_ticks", "slowed_s",
                                          "effort_waits", "effort_wait_timeouts",
                                          "scheduling")}
        res.overruns = sim["late_ticks"]
