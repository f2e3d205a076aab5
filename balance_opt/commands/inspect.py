"""What looks at the input without planning: ``validate`` (task files), ``inspect`` (a robot's
summary, its geometry, ``--write-srdf``) and ``robots``."""

from __future__ import annotations

import sys
from pathlib import Path

from balance_opt.commands.common import (
    EXIT_INPUT,
    EXIT_OK,
    count,
    load_task_file,
    methods_of,
    print_cartesian_goal,
    reference_asked,
)


def _print_joint_lines(chains) -> None:
    """Each chain's joints, one line a chain; nothing for a robot without movable joints."""
    for k, chain in enumerate(chains, 1):
        print(f"    chain {k}: {', '.join(map(str, chain))}")


def cmd_robots(args) -> int:
    from balance_opt.model.library import ALIASES, example_robots, robot_info

    if args.name:
        info = robot_info(args.name)
        print(f"{info.name}: {info.path}")
        if info.error:
            print(f"  does not load: {info.error}")
            return 2
        joints, chains = count(info.dof, "movable joint", "movable joints"), len(info.chains)
        print(f"  {joints}, {count(chains, 'chain', 'chains')}, {info.mass:.2f} kg")
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
        info = robot_info(name, robots)
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


def cmd_inspect(args) -> int:
    from balance_opt.errors import InputError
    from balance_opt.model.summary import robot_summary
    from balance_opt.model.symbolic import backend_description  # builds the bridge if used

    srdf = None if args.write_srdf is None else Path(args.write_srdf)
    if srdf is not None and args.task is None:
        raise InputError("inspect --write-srdf: give a task file (its robot, locks and ignores)")
    if srdf is not None and srdf.exists() and not args.force:  # before the work, not after
        raise InputError(f"{srdf} exists; use --force to replace it, or choose another file")
    if args.task is None:
        from balance_opt.model.library import paper_robot

        print(robot_summary(paper_robot()))
        print(f"symbolic backend: {backend_description(args.backend or 'auto')}")
        return EXIT_OK
    task = load_task_file(args.task, args.backend)
    print(f"task {task.name} ({task.source}, sha256 {task.sha256[:12]})")
    print(robot_summary(task.robot, task.q0))
    print_cartesian_goal(task)
    geometry = _print_geometry(task)
    print(f"symbolic backend: {backend_description(task.spec.robot.backend)}")
    if srdf is not None:
        _write_srdf(task, geometry, srdf)
    return EXIT_OK


def _write_srdf(task, geometry, path: Path) -> None:
    """The SRDF of the pairs the robot leaves out (not the task's), for the user to review."""
    from balance_opt.errors import InputError
    from balance_opt.geometry.self_collision import srdf_text
    from balance_opt.report.output_dir import replaced_atomically

    if geometry is None:
        raise InputError(f"--write-srdf {path}: the robot's geometry is not loaded")
    text = srdf_text(task.robot.name, geometry.disabled)
    with replaced_atomically(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    print(f"wrote {path}: {len(geometry.disabled)} disabled link pairs")


def _print_geometry(task):
    """What the clearance check and the planner's collision avoidance hold apart (the task's
    ignored pairs and SRDF applied, or the computed pairs) and the pairs already close at the
    initial configuration; the geometry, or None when it does not load."""
    from balance_opt.errors import InputError
    from balance_opt.geometry.robot_geometry import NoGeometryError, RobotGeometry
    from balance_opt.geometry.self_collision import NEAR

    planner = task.spec.optimal.planner
    try:
        geometry = RobotGeometry(
            task.robot, srdf=planner.collision_srdf, ignore=planner.collision_ignore
        )
    except NoGeometryError as exc:
        print(f"geometry: none ({exc}): no clearance check, no collision avoidance")
        return None
    except InputError as exc:
        print(f"geometry: not loaded ({exc})")
        return None
    s = geometry.summary(task.q0, planner.collision_margin)
    left_out = s["link_pairs_ignored"]
    print(
        f"geometry from the URDF's <{s['source']}> elements: {s['pairs_checked']} pairs checked; "
        f"link pairs left out: {left_out['same body']} same body, {left_out['adjacent']} "
        f"adjacent, {left_out['srdf']} by the SRDF, "
        f"{left_out['default'] + left_out['always'] + left_out['near']} computed, "
        f"{left_out['ignored']} ignored by the task"
    )
    if s["srdf"] is not None:
        print(f"  pairs left out by the SRDF {s['srdf']}")
    else:
        print(
            f"  pairs left out computed (no SRDF): {left_out['adjacent']} adjacent, "
            f"{left_out['default']} in the reference pose, {left_out['always']} in nearly "
            f"every sampled configuration, {left_out['near']} one body apart and never more "
            f"than {NEAR:g} m apart ({s['samples']} samples)"
        )
        reasons = ("default", "reference pose"), ("always", "nearly always"), ("near", "near")
        for reason, what in reasons:
            pairs = [f"{a} / {b}" for (a, b), r in sorted(geometry.ignored.items()) if r == reason]
            if pairs:
                print(f"    {what}: {', '.join(pairs)}")
    close = s["initial_contacts"] + s["initial_within_margin"]
    if not close:
        print(f"  at the initial configuration every pair is at least {s['margin_m']:g} m apart")
    for kind, items in (
        ("in contact", s["initial_contacts"]),
        (f"within the margin {s['margin_m']:g} m", s["initial_within_margin"]),
    ):
        if items:
            pairs = ", ".join(f"{c['pair']} ({c['distance_m']:.4f} m)" for c in items)
            print(f"  {kind} at the initial configuration: {pairs}")
    if s["initial_contacts"]:
        print(
            "  (the task starts in collision: the optimal planner refuses it; move the initial "
            "configuration, or leave the pairs out with robot.srdf or optimal.collision.ignore)"
        )
    return geometry


def cmd_validate(args) -> int:
    """Check every task file given, each error printed with its file; exit 2 if any failed."""
    from balance_opt.errors import InputError
    from balance_opt.tasks.task import check_methods, load_task
    from balance_opt.tasks.task_spec import task_json_schema, task_reference_markdown

    if reference_asked(args, task_json_schema, task_reference_markdown):
        return EXIT_OK
    if not args.tasks:
        raise InputError("validate: give one or more task files, or --schema")
    failed = 0
    for path in args.tasks:
        try:
            task = load_task(path)
            check_methods(task, methods_of(args))
        except InputError as exc:
            failed += 1
            message = str(exc)
            if not message.startswith(str(path)):
                message = f"{path}: {message}"
            print(f"balance-opt: error: {message}", file=sys.stderr)
            continue
        robot = task.robot
        arms = "; ".join(f"{a.name} {a.dof} joints" for a in robot.arms)
        print(
            f"{path}: ok (robot {robot.name}, {arms}; mission {task.spec.mission.type}, "
            f"{task.duration:.3g} s)"
        )
    if failed and len(args.tasks) > 1:
        print(f"{failed} of {len(args.tasks)} task files failed")
    return EXIT_INPUT if failed else EXIT_OK
