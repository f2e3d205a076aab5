"""The optimal balance planner: the paper's balance law (Eq. 31) posed as an optimal control
problem, transcribed by direct collocation and solved with Ipopt.

The balance arm's motion is chosen to keep the largest base rotation ``max |log R(t)|`` small
(objective ``peak``, the default; ``integral``: the integral of ``|omega_b|^2`` and
``|log R|^2``), to bring the attitude back at the end (``|log R_T|^2``: the motion is
non-holonomic, so a closed joint path can undo a rotation), and to stay smooth, while every
balance joint respects its position, velocity and acceleration limits on the whole continuous
motion (optionally its torque limits, held on the re-simulated motion by refinement), starting
and by default ending at rest. The mission arm's motion is a hard input. Assumptions: a
constant total momentum ``h0`` (a parameter, zero by default), the base at the identity and
the balance arm at rest at ``q_B0`` at ``t = 0``. The physics is in ``docs/physics.md``
("Base motion forced by the joints", "The balance law", "Attitude").

Use::

    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp, plan_optimal

    nlp = build_balance_nlp(PlannerModel(robot), mission, q_B0, PlannerOptions(intervals=100))
    result = nlp.solve()          # a BalanceResult: the plan, re-simulated

or in one call ``plan_optimal(robot, mission, q_B0, options)``. Importing this package does not
import CasADi; its modules do.

The modules, how a plan is solved and how to add a constraint: ``docs/architecture.md``.
"""
