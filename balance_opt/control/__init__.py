"""The closed-loop controller (``docs/executable-plans.md``, "Closed loop"): a stage above the
planner and the simulation. ``replan`` re-plans a plan's tail from a measured state with the
planner of :mod:`balance_opt.optimal`; ``flight`` flies a plan on a true robot in the forward
dynamics of :mod:`balance_opt.dynamics`, re-planned every period."""
