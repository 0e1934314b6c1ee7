"""Option types shared by the command lines (``flexarm`` and its ensemble commands): a
value that does not parse is an argparse error naming the value and the expectation
(range checks come later, with the option's name)."""

from __future__ import annotations

import argparse


def number(text):
    """An option's number: got 'abc', expected a number."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"got {text!r}, expected a number") from None


def integer(text):
    """An option's integer: got '1.5', expected an integer."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"got {text!r}, expected an integer") from None


#: ``--open-loop`` of every batch command (flexarm_ros.twin.batch.run_scene)
OPEN_LOOP_HELP = ("run the scene's input programs alone, continuously, even when it "
                  "declares a controller (control:); by default such a scene runs as the "
                  "twin does: controller and motor driver in the loop at control.rate_hz, "
                  "efforts held over each period")


SET_HELP = ("set a scene value before the model is built: KEY is a scene key path as "
            "flexarm sweep --param takes it (links[0].joint.drive.resistance, "
            "tool.position[0], control.kp[0], fidelity.rung), VALUE a YAML scalar or flow "
            "value (6.0, [6.0, 8.0], true, modal); checked by the scene's schema, applied "
            "before the fidelity flags (an explicit --rung etc. wins; a fidelity key set here "
            "stays set when a flag such as --refine changes the model); repeatable")


def set_option(parser, help_text: str = SET_HELP) -> None:
    """``--set KEY=VALUE`` (repeatable; parsed by the command with
    :func:`flexarm_ros.scene.overrides.parse_sets`, so that a bad one is the command's
    one-line error naming key, value and expectation)."""
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", dest="set",
                        help=help_text)
