"""balance-opt: balance-arm motion planning for free-floating multi-arm space robots.

The pipeline, one module each: ``robot`` (URDF on a free-flying base, arms by joint names),
``symbolic`` and ``momentum`` (CasADi and Pinocchio momentum maps), ``trajectories`` (mission
motions), ``attitude`` (SO(3)), ``result`` (the plan type every method returns).
"""

from balance_opt.errors import BalanceOptError, InputError, SolverError
from balance_opt.model.library import baxter_floating, paper_robot
from balance_opt.model.robot import Arm, FloatingRobot, JointLimits

__version__ = "0.1.0"

__all__ = [
    "Arm",
    "BalanceOptError",
    "FloatingRobot",
    "InputError",
    "JointLimits",
    "SolverError",
    "__version__",
    "baxter_floating",
    "paper_robot",
]
