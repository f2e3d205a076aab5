"""``view``: the 3D scene page of a result folder or a task file, opened in a browser."""

from __future__ import annotations

import json
from pathlib import Path

from balance_opt.commands.common import EXIT_OK, load_task_file, log


def _scene_page(source: Path, backend: str | None, folder: Path) -> Path:
    """The scene page of a result folder (its ``scene.html``, or one built into ``folder`` from
    its NPZ files and task file) or of a task file (planned here, both methods)."""
    from balance_opt.app.pipeline import run_task
    from balance_opt.app.run_files import METRICS_FILE, SCENE_FILE, write_run_scene
    from balance_opt.app.task_run import METHODS, REFERENCE, TaskRun
    from balance_opt.errors import InputError

    scene, metrics = SCENE_FILE, source / METRICS_FILE
    if not source.is_dir():
        run = run_task(load_task_file(source, backend), methods=METHODS)
        return write_run_scene(run, folder / scene)
    if (source / scene).is_file():
        return source / scene
    from balance_opt.report.outputs import read_npz_result

    if not metrics.is_file():
        raise InputError(f"{source}: no {scene} and no {metrics.name}: not a result folder")
    content = json.loads(metrics.read_text())
    task_file = content.get("task", {}).get("file", "")
    if not Path(task_file).is_file():
        raise InputError(
            f"{metrics}: task file '{task_file}' not found (the scene needs its robot)"
        )
    names = (REFERENCE, *METHODS)
    results = {n: read_npz_result(f) for n in names if (f := source / f"{n}.npz").is_file()}
    if not results:
        raise InputError(f"{source}: no NPZ trajectories (outputs.npz was off?)")
    failures = content.get("failures") or {}
    run = TaskRun(load_task_file(task_file, backend), results=results, failures=failures)
    return write_run_scene(run, folder / scene)


def cmd_view(args) -> int:
    import tempfile
    import webbrowser

    # a scene built here (of a task, or of an older result folder, which stays as it was) is
    # kept for the browser to read after the command ends
    folder = Path(tempfile.mkdtemp(prefix="balance-opt-view-"))
    try:
        page = _scene_page(Path(args.source), args.backend, folder).resolve()
    finally:
        if not any(folder.iterdir()):  # the result folder's own page, or an error
            folder.rmdir()
    print(page, flush=True)
    if args.no_browser:
        return EXIT_OK
    if webbrowser.open(page.as_uri(), new=2):
        log.info("opened %s in a browser", page.as_uri())
    else:
        log.warning("no browser found: open %s in one (the file is self-contained)", page)
    return EXIT_OK
