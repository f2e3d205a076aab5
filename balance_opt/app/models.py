"""Planner models kept for reuse: one :class:`~balance_opt.optimal.model.PlannerModel` per robot
kinematics, in an explicit cache object that its owner passes around.

Building a model and its compiled NLPs takes seconds, longer than solving a case. The key is the
robot's kinematic and inertial content, not the Python object, so two tasks that load the same
robot share a model. Joint limits are not part of it: they are numeric bounds of the NLP."""

from __future__ import annotations

from typing import TYPE_CHECKING

from balance_opt.cache import kinematics_key

if TYPE_CHECKING:
    from balance_opt.model.robot import FloatingRobot
    from balance_opt.optimal.model import PlannerModel


class ModelCache:
    """Planner models by robot kinematics (see the module docstring).

    Args:
        compile: how the models compile their point kernels (``PlannerModel``'s ``compile``:
            ``"auto"`` before the first plan, ``"background"`` while it runs on the VM, ``True``
            now, ``False`` never).
    """

    def __init__(self, compile: bool | str = "auto"):
        self.compile = compile
        self._models: dict[str, PlannerModel] = {}

    def planner_model(self, robot: FloatingRobot, backend: str = "auto") -> PlannerModel:
        """The planner model of ``robot``'s kinematics, built on first use with the symbolic
        ``backend`` (``"auto"``, ``"pinocchio"`` or ``"adam"``, see
        :class:`~balance_opt.model.symbolic.SymbolicMaps`).

        The model may have been built for another robot object of the same kinematics (other
        limits): plan with ``robot`` next to it, never with ``model.robot``.
        """
        from balance_opt.optimal.model import PlannerModel

        key = f"{kinematics_key(robot)}/{backend}"
        model = self._models.get(key)
        if model is None:  # built lazily: its functions when a plan first asks for them
            model = PlannerModel(robot, compile=self.compile, backend=backend)
            self._models[key] = model
        else:
            model.upgrade_kernels()  # a background compilation may have finished meanwhile
        return model

    def collisions(self, robot: FloatingRobot, backend: str = "auto"):
        """The collision models (:class:`~balance_opt.optimal.collision.CollisionModels`) of
        the planner model of ``robot``'s kinematics and ``backend`` if one was built (nothing is
        built for this), else ``None``."""
        model = self._models.get(f"{kinematics_key(robot)}/{backend}")
        return None if model is None else model.collisions

    def __len__(self) -> int:
        return len(self._models)

    def __contains__(self, robot: FloatingRobot) -> bool:
        return any(key.startswith(kinematics_key(robot)) for key in self._models)
