"""The per-robot symbolic model of the planner, kept on disk: its CasADi functions saved once,
loaded by every later run instead of being built again."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from balance_opt.cache import (
    MODELS_FOLDER,
    build_dir,
    default_cache_dir,
    file_lock,
    load_checked,
    lock_path,
    write_record,
)

if TYPE_CHECKING:  # casadi is imported where used: kinematics_key stays a light import
    import casadi as cs

    from balance_opt.model.robot import FloatingRobot

log = logging.getLogger(__name__)

#: The modules whose code decides the planner's symbolic functions.
FORMULATION_MODULES = (
    "balance_opt.optimal.model",
    "balance_opt.optimal.model_store",
    "balance_opt.model.symbolic",
    "balance_opt.model.coupling",
    "balance_opt.model.robot",
    "balance_opt.model.joints",
    "balance_opt.model.bridge",
    "balance_opt.motion.so3_casadi",
)


def kinematics_key(robot: FloatingRobot) -> str:
    """SHA-256 of what a planner model depends on: the locked URDF (links, joints, inertia,
    locked positions), the arm joints in order and the end-effector frames."""
    content = {
        "urdf": robot.locked_urdf,
        "joints": list(robot.joint_names),
        "arms": [[arm.name, list(arm.joints), arm.ee_frame] for arm in robot.arms],
    }
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def formulation_fingerprint() -> str:
    """Hash of the source of :data:`FORMULATION_MODULES` and of CasADi's version."""
    import casadi as cs

    digest = hashlib.sha256(cs.__version__.encode())
    for name in FORMULATION_MODULES:
        spec = importlib.util.find_spec(name)
        digest.update(Path(spec.origin).read_bytes() if spec and spec.origin else name.encode())
    return digest.hexdigest()


def model_key(robot: FloatingRobot, backend_identity: str) -> str:
    """The content key of a robot's planner model built with a backend (see the module)."""
    parts = [kinematics_key(robot), backend_identity, formulation_fingerprint()]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:20]


class FunctionStore:
    """Named lists of CasADi functions of one planner model, on disk."""

    def __init__(self, label: str, key: str, cache_dir: str | Path | None = None):
        root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self.folder = root / MODELS_FOLDER
        self.prefix = f"{re.sub(r'[^A-Za-z0-9._-]+', '_', label)[:40]}_{key}"

    def path(self, name: str) -> Path:
        return self.folder / f"{self.prefix}_{name}.casadi"

    def get(self, name: str, make: Callable[[], list[cs.Function]]) -> list[cs.Function]:
        """The functions saved as ``name`` (a damaged file deleted), else ``make()``'s, saved (a
        failure to write is only logged: the cache only saves time)."""
        import casadi as cs

        path = self.path(name)
        functions = load_checked(
            path,
            lambda p: list(cs.FileDeserializer(str(p)).unpack()),
            f"planner model {path}",
            "building it again",
        )
        if functions is not None:
            return functions
        functions = make()
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with file_lock(lock_path(path)), build_dir(self.folder, path.stem) as tmp:
                out = tmp / path.name
                serializer = cs.FileSerializer(str(out))
                serializer.pack(functions)
                del serializer  # closes the file
                os.replace(out, path)
                write_record(path)
        except (OSError, RuntimeError) as exc:
            log.warning("planner model not cached (%s): %s", path, exc)
        return functions
