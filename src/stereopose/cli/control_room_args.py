"""The command line of `stereopose control-room`: its actions and the `sites` verbs, each with
its own help, and the form it had before them (`control-room CONFIG.toml`) still taken."""

from __future__ import annotations

import argparse
from pathlib import Path

CONTROL_ROOM_ACTIONS = ("run", "sites", "broker-config")


def add_control_room(cr: argparse.ArgumentParser) -> None:
    """`control-room run CONFIG.toml` (`control-room CONFIG.toml` still), `control-room sites
    add|list|remove`, `control-room broker-config`, each with its own help."""
    config_help = "the control room's configuration (output, [serve], [mqtt], [control_room])"
    actions = cr.add_subparsers(dest="cr_action", required=True, metavar="ACTION")
    run = actions.add_parser(
        "run",
        help="run the control room (also: control-room CONFIG.toml)",
        description="Many sites' events in one store, over the central broker, until Ctrl-C "
        "or SIGTERM.",
    )
    # one file; more is refused with the reason by the command (nargs: its own message)
    run.add_argument("config", nargs="+", type=Path, metavar="CONFIG.toml", help=config_help)
    sites = actions.add_parser("sites", help="the sites it takes: add, list, remove")
    verbs = sites.add_subparsers(dest="sites_action", required=True, metavar="VERB")
    for verb, help_text, names in (
        ("add", "enrol sites, each given its own broker login (shown once)", "the sites' names"),
        ("list", "the sites enrolled, and whether each has a broker login", None),
        ("remove", "refuse a site's messages from now on (what it sent stays)", "their names"),
    ):
        v = verbs.add_parser(verb, help=help_text, description=help_text[0].upper() + help_text[1:])
        v.add_argument(
            "names", nargs="*", metavar="NAME", help=names or argparse.SUPPRESS, default=[]
        )
        v.add_argument("--config", type=Path, metavar="CONFIG.toml", help=config_help)
        if verb == "add":
            v.add_argument(
                "--bridge", type=Path, metavar="FILE", help="write the site's bridge file here"
            )
    bc = actions.add_parser(
        "broker-config",
        help="the central broker's password file and ACL for the sites enrolled",
    )
    bc.add_argument("--config", type=Path, metavar="CONFIG.toml", help=config_help)
    bc.add_argument("--out", type=Path, metavar="DIR", help="the files' folder")


def control_room_argv(argv: list[str]) -> list[str]:
    """`control-room CONFIG.toml` as `control-room run CONFIG.toml` (the form before the
    control room had subcommands)."""
    for i, word in enumerate(argv):
        if word.startswith("-"):
            continue
        if word == "control-room" and i + 1 < len(argv):
            nxt = argv[i + 1]
            if nxt not in CONTROL_ROOM_ACTIONS and not nxt.startswith("-"):
                return [*argv[: i + 1], "run", *argv[i + 1 :]]
        return argv
    return argv
