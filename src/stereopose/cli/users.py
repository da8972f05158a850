"""`stereopose users add|list|remove|passwd`: the operator console's users of a service.

The users live in the service's output folder (`<output>/users.json`, see web.users),
named by its configuration (`--config CONFIG.toml`). A password is read from standard input:
asked twice without echo on a terminal, one line from a pipe. A running service sees the
change at its next request; a removed user's or a changed password's sessions end.
"""

from __future__ import annotations

import argparse
import getpass
import sys
from pathlib import Path

from stereopose.cli.common import out
from stereopose.errors import ConfigError, StereoposeError


def users_file(config: Path) -> Path:
    """`<output>/users.json` of the configuration at `config` (output relative to its folder)."""
    from stereopose.config import load_config
    from stereopose.io.datafolder import USERS_FILE

    if not config.exists():
        raise ConfigError(f"{config}: configuration file not found")
    cfg = load_config(config)
    if not cfg.output:
        raise ConfigError(f"{config}: output: the service's folder is not set")
    output = Path(cfg.output).expanduser()
    if not output.is_absolute():
        output = config.resolve().parent / output
    return output / USERS_FILE


def read_password(prompt: str = "password") -> str:
    """The password from standard input (see the module)."""
    if sys.stdin is not None and sys.stdin.isatty():
        first = getpass.getpass(f"{prompt}: ")
        if getpass.getpass(f"{prompt} again: ") != first:
            raise StereoposeError("the two passwords differ; nothing changed")
        return first
    line = sys.stdin.readline() if sys.stdin is not None else ""
    return line.removesuffix("\n").removesuffix("\r")


def _users(args: argparse.Namespace) -> int:
    from stereopose.web.users import UserStore, check_name, check_password

    store = UserStore(users_file(args.config))
    action = args.action
    if action == "list":
        users = store.users()
        if not users:
            out.print(f"no users in {store.path}", highlight=False, soft_wrap=True)
        for u in users:
            sites = "" if u.sites is None else "\t" + ",".join(u.sites)
            out.print(f"{u.name}\t{u.role}{sites}", highlight=False, markup=False)
        return 0
    if not args.name:
        raise StereoposeError(f"users {action}: give the user's NAME")
    name = check_name(args.name)
    if action == "add":
        if args.role is None:
            raise StereoposeError("users add: give the role: --role viewer|operator|admin")
        if store.get(name) is not None:
            raise StereoposeError(
                f"user {name!r} already exists in {store.path} "
                "(`stereopose users passwd` changes a password)"
            )
        sites = None
        if getattr(args, "sites", None):
            sites = tuple(x.strip() for x in args.sites.split(",") if x.strip())
            if not sites:
                raise StereoposeError("users add: --sites: give one site name or more")
        store.add(name, check_password(read_password()), args.role, sites)
        limit = f", sites {', '.join(sites)}" if sites else ""
        out.print(
            f"added {name} ({args.role}{limit}) to {store.path}", highlight=False, soft_wrap=True
        )
    elif action == "passwd":
        if store.get(name) is None:
            raise StereoposeError(f"no user {name!r} in {store.path}")
        store.set_password(name, check_password(read_password("new password")))
        out.print(f"changed the password of {name}; their sessions are ended", highlight=False)
    else:
        if store.get(name) is None:
            raise StereoposeError(f"no user {name!r} in {store.path}")
        store.remove(name)
        out.print(f"removed {name}; their sessions are ended", highlight=False)
    return 0
