"""The optimal balance planner: the paper's balance law (Eq. 31) posed as an optimal control
problem, transcribed by direct collocation and solved with Ipopt."""
