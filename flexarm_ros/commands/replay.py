"""``flexarm replay``: publish a recorded bag on ROS 2 with /clock, and/or convert it to
rerun (:mod:`flexarm_ros.replay`)."""

from __future__ import annotations

from pathlib import Path

from flexarm_ros.io.arguments import integer, number


def add_parser(sub) -> None:
    rp = sub.add_parser("replay", help="publish a recorded bag on ROS 2 with /clock (no "
                                       "rosbag2 needed) and/or convert it to rerun")
    rp.add_argument("bag", type=Path, metavar="BAG.mcap", help="MCAP bag (flexarm run's or "
                                                               "any ROS 2 MCAP)")
    rp.add_argument("--rate", type=number, default=1.0,
                    help="pace factor on the log times: 1 real time (default), 2 twice as "
                         "fast, 0 as fast as possible")
    rp.add_argument("--namespace", help="republish the recording namespace's topics under "
                                        "this one instead")
    rp.add_argument("--topics", nargs="+", metavar="TOPIC",
                    help="only these topics (absolute, or relative to the recording "
                         "namespace); /clock is always published")
    rp.add_argument("--loop", action="store_true", help="start over at the end until Ctrl-C")
    rp.add_argument("--wait-subscribers", type=integer, default=0, metavar="N",
                    help="before publishing, wait up to 30 s until every topic has N "
                         "subscribers (default 0: do not wait)")
    rp.add_argument("--delay", type=number, default=0.5, metavar="S",
                    help="wall seconds between creating the publishers and the first "
                         "message, for discovery (default 0.5)")
    rp.add_argument("--rerun", type=Path, metavar="FILE.rrd",
                    help="convert the bag to this rerun recording instead of publishing "
                         "(no ROS needed; with --publish: both)")
    rp.add_argument("--publish", action="store_true", help="with --rerun: also publish")
    rp.add_argument("--shape-rate", type=number, default=100.0, metavar="HZ",
                    help="--rerun: at most this many arm drawings per simulated second "
                         "(default 100; 0: every coordinates message)")
    rp.add_argument("--samples", type=integer, default=21,
                    help="--rerun: points per beam centerline (default 21)")
    rp.add_argument("--force-scale", type=number, metavar="M_PER_N",
                    help="--rerun: contact force arrow length per newton (default: the "
                         "largest force draws a quarter of the arm's reach)")
    rp.add_argument("--json", action="store_true", help="print the counts as JSON")
    rp.add_argument("--quiet", action="store_true",
                    help="no progress on stderr (the summary is still printed)")
    rp.set_defaults(func=main)


def main(args):
    """Publish a bag on ROS 2 with /clock and/or convert it to rerun (flexarm_ros.replay)."""
    from flexarm_ros.replay import command
    return command(args)
