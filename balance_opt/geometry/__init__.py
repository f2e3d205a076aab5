"""The bodies' volume: the robot's geometry (:mod:`~balance_opt.geometry.robot_geometry`), the
clearance of a motion on its continuous path (:mod:`~balance_opt.geometry.clearance`), and the
smooth shapes that contain each body and the planner's distance constraints are written with
(:mod:`~balance_opt.geometry.shapes`). ``docs/collision.md`` explains them.

This stage imports only :mod:`balance_opt.model` and below; the optimal planner imports it.
"""
