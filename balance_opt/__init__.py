"""balance-opt: balance-arm motion planning for free-floating multi-arm space robots.

The stages, one subpackage each:

* ``model``: the robot (URDF on a free-flying base, arms by joint names) and its momentum maps,
  numeric (Pinocchio) and symbolic (CasADi);
* ``motion``: joint trajectories, SO(3) attitude, the kinematic replay of joint motions and the
  momentum check of a sampled motion;
* ``analytic``: the paper's balance law, its rollout and its phases; ``optimal``: the optimal
  planner (NLP);
* ``dynamics``: forward-dynamics simulation of a plan and the wrenches on the base;
* ``io``: task files, output files, figures and the HTML report;
* ``app``: running a task end to end (``pipeline``), the paper's study; ``sweep``: many tasks.

``result`` holds the plan type every method returns, ``errors`` the exceptions, ``cli`` the
``balance-opt`` command. Importing the package loads the robot model (Pinocchio), not CasADi.
"""

from balance_opt.errors import BalanceOptError, InputError, SolverError
from balance_opt.model.arms import Arm, JointLimits
from balance_opt.model.library import baxter_floating, paper_robot
from balance_opt.model.robot import FloatingRobot

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
