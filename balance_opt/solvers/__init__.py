"""Numerical tools that know nothing of robots: CasADi functions compiled to C with an on-disk
cache (``codegen``), Ipopt's options checked against its own list and its version
(``ipopt_options``). The optimal planner is their user."""
