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

The modules, top down:

* :mod:`~balance_opt.optimal.options`: the settings (:class:`PlannerOptions`,
  :class:`CostWeights`).
* :mod:`~balance_opt.optimal.solve`: :func:`build_balance_nlp`, :class:`BalanceNLP` (inspect its
  vectors and bounds, :meth:`~BalanceNLP.solve` it), :func:`plan_optimal`, :func:`resimulate`
  and :class:`PlannerSolverError`. Every plan is re-simulated on a fine grid with numeric
  Pinocchio, and the returned result is that re-simulated motion.
* :mod:`~balance_opt.optimal.refine`: the outer loop of :meth:`~BalanceNLP.solve`: the peak
  problem in three stages (the integral plan and a smooth L16 peak on a coarser grid, the
  epigraph), path attitude bounds reached through the peak problem, bounds tightened until
  the re-simulated motion meets them.
* :mod:`~balance_opt.optimal.ledger`: the Ipopt work behind one plan (every solve's
  iterations and time, failed ones included), which the results and ``metrics.json`` report.
* :mod:`~balance_opt.optimal.starts`: multi-start in this process and parallel worker
  processes, starts that reach the same first plan merged;
  :mod:`~balance_opt.optimal.start_schedule`: which of its tasks runs where and when.
* :mod:`~balance_opt.optimal.problem`: one problem's numeric data (mission samples, horizon,
  limits), checked against the robot.
* :mod:`~balance_opt.optimal.nlp`: the compiled NLP of one structure, assembled from per-point
  kernels with exact derivatives by the chain rule. It depends only on the structure
  (:class:`~balance_opt.optimal.layout.StructureKey`: intervals, transcription, control, which
  constraints, solver options) and is cached on the model; the mission, horizon, ``q_B0``,
  weights and bounds are numeric inputs, so another problem of the same structure costs no
  build.
* :mod:`~balance_opt.optimal.layout`: where everything sits in the NLP's decision, parameter and
  constraint vectors.
* :mod:`~balance_opt.optimal.constraints`: the constraint kinds, and what holds where (on the
  continuous motion, or at the collocation points).
* :mod:`~balance_opt.optimal.collision`: collision avoidance (on by default): the pairs a
  problem keeps apart, its rows, their check with exact distances and their refinement
  (``docs/collision.md``).
* :mod:`~balance_opt.optimal.guess`: the initial guesses.
* :mod:`~balance_opt.optimal.collocation`: the transcriptions and the continuous, piecewise
  polynomial motion of the balance joints they describe.
* :mod:`~balance_opt.optimal.model`: the per-robot symbolic model (state, dynamics and running
  cost of one collocation point, inverse dynamics) and its point kernels.
* :mod:`~balance_opt.optimal.model_store`: the per-robot model's functions saved on disk.
* :mod:`~balance_opt.optimal.codegen`: compiling the kernels to C (in the background while
  the first plan runs on CasADi's VM), cached on disk.

How to add a constraint. Everything about a constraint lives in one class in
:mod:`~balance_opt.optimal.constraints`, a subclass of ``Constraint``: ``rows`` returns the rows
it adds to the constraint vector, symbolic in the decision variables, the point kernels' outputs
and the parameters (``SymbolicNLP``), with a block name and a label per row (Ipopt's failure
messages name the constraint by them); ``row_bounds`` gives their lower and upper bounds for one
problem; ``bound_variables`` narrows the decision variables' bounds instead, or as well; and
``check`` returns its worst violation by the re-simulated motion (reported in
``info["resimulation"]["constraint_violations"]``). Then list it in ``constraint_kinds``. If an
option switches it on, add that switch to ``StructureKey.of`` (problems with and without it need
different compiled NLPs) and the option to ``PlannerOptions``; numbers for its bounds are read
from the problem when the bounds are set, but a number inside its rows must be a parameter: a
field of ``NLPParameters`` (sized in ``ParameterLayout``, valued where ``BalanceNLP`` packs the
parameters). A new nonlinear quantity at the points (as the torques are) goes into the point
kernels' output (``PlannerModel`` kernels and ``PointKernels.split``): the rows must stay linear
in the kernels' outputs.
"""
