"""URDF files shipped with balance-opt (installed as the package ``balance_opt.urdf``)."""
