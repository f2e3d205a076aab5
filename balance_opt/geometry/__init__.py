"""The bodies' volume: geometry, clearance of a motion, and the smooth shapes of the planner's
distance constraints (``docs/collision.md``)."""
