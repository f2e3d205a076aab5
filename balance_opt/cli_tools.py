"""The housekeeping subcommands of ``balance-opt``: ``cache`` and ``robots``."""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os

EXIT_OK = 0


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def _cmd_cache(args) -> int:
    from balance_opt.cache import (
        CACHE_ENV,
        KINDS,
        LIMIT_ENV,
        clear,
        default_cache_dir,
        entries,
        format_size,
        size_limit,
    )

    folder = default_cache_dir()
    origin = f"${CACHE_ENV}" if os.environ.get(CACHE_ENV) else "default; set $" + CACHE_ENV
    print(f"cache folder: {folder} ({origin})")
    if not folder.is_dir():
        print("empty (the folder does not exist yet)")
        return EXIT_OK
    if args.clear:
        deleted, kept = clear(folder)
        size = sum(e.size for e in deleted)
        print(f"deleted {_count(len(deleted), 'entry', 'entries')} ({format_size(size)})")
        for entry in kept:
            print(f"kept {entry.name}: a build under way in another process")
        return EXIT_OK
    found = entries(folder)
    total = sum(e.size for e in found)
    print(f"size: {format_size(total)} (bound {format_size(size_limit())}, ${LIMIT_ENV})")
    for kind in KINDS:
        group = [e for e in found if e.kind == kind]
        if not group:
            continue
        print(
            f"{kind}: {_count(len(group), 'entry', 'entries')}, {format_size(sum(e.size for e in group))}"
        )
        if not args.list:
            continue
        for e in group:
            used = datetime.datetime.fromtimestamp(e.last_used).strftime("%Y-%m-%d %H:%M")
            print(f"  {e.name}  {format_size(e.size)}  last used {used}")
    if found and not args.list:
        print("--list shows every entry")
    return EXIT_OK


def _print_joint_lines(chains) -> None:
    """Each chain's joints, one line a chain; nothing for a robot without movable joints."""
    for k, chain in enumerate(chains, 1):
        print(f"    chain {k}: {', '.join(map(str, chain))}")


def _cmd_robots(args) -> int:
    from balance_opt.model.catalog import ALIASES, example_robots, robot_info

    if args.name:
        info = robot_info(args.name)
        print(f"{info.name}: {info.path}")
        if info.error:
            print(f"  does not load: {info.error}")
            return 2
        joints, chains = _count(info.dof, "movable joint", "movable joints"), len(info.chains)
        print(f"  {joints}, {_count(chains, 'chain', 'chains')}, {info.mass:.2f} kg")
        _print_joint_lines(info.chains)
        for warning in info.warnings:
            print(f"  warning: {warning}")
        return EXIT_OK
    aliases = {}
    for alias, name in ALIASES.items():
        aliases.setdefault(name, []).append(alias)
    failed = []
    robots = example_robots()
    for name in robots:
        info = robot_info(name)
        if info.error:
            failed.append(info)
            continue
        also = f" (also: {', '.join(aliases[name])})" if name in aliases else ""
        print(f"{name}{also}: {info.dof} movable joints, {info.mass:.1f} kg")
        _print_joint_lines(info.chains)
    print(f"{len(robots) - len(failed)} of {len(robots)} robots load; use robot: {{example: NAME}}")
    for info in failed:
        print(f"does not load: {info.name}: {info.error}")
    return EXIT_OK


def backend_option(parser: argparse.ArgumentParser) -> None:
    """``--backend``: the symbolic backend, overriding the task's ``robot.backend``."""
    parser.add_argument(
        "--backend",
        choices=("auto", "pinocchio", "adam"),
        help="symbolic backend of the optimal planner (default: the task's robot.backend, auto)",
    )


def with_backend(task, backend: str | None):
    """``task`` with ``robot.backend`` replaced by ``backend`` (unchanged when ``None``)."""
    if backend is None:
        return task
    robot = dataclasses.replace(task.spec.robot, backend=backend)
    return dataclasses.replace(task, spec=dataclasses.replace(task.spec, robot=robot))


def backend_line(backend: str) -> str:
    """``symbolic backend: pinocchio (...)`` or ``symbolic backend: adam (...)`` for
    ``balance-opt inspect`` (builds the Pinocchio-CasADi bridge first if it may be used)."""
    from balance_opt.model.symbolic import backend_description

    return f"symbolic backend: {backend_description(backend)}"


def add_tool_commands(sub) -> None:
    """Register ``cache`` and ``robots`` on the subcommand parser ``sub``."""
    p = sub.add_parser(
        "cache", help="show the cache of compiled kernels and the bridge, or clear it"
    )
    p.add_argument("--clear", action="store_true", help="delete every cached entry")
    p.add_argument("--list", action="store_true", help="list every entry (default: a summary)")
    p.set_defaults(run=_cmd_cache)

    p = sub.add_parser("robots", help="robots usable as robot.example, with their joints by chain")
    p.add_argument("name", nargs="?", help="one robot in detail")
    p.set_defaults(run=_cmd_robots)
