"""Exceptions of balance-opt. Every error a user can cause derives from :class:`BalanceOptError`
and names the file, key, joint or constraint at fault; the CLI exits with 2 (bad input) or 1
(solver failure)."""

from __future__ import annotations


class BalanceOptError(Exception):
    """Base class of every error balance-opt raises on purpose."""


class InputError(BalanceOptError):
    """Bad input: a file, a key, a joint or a value the user gave. CLI exit code 2."""


class URDFLoadError(InputError):
    """A URDF that cannot be read or parsed."""

    def __init__(self, source: str, reason: str):
        self.source = source
        self.reason = reason
        super().__init__(f"cannot load URDF {source}: {reason}")


class JointError(InputError):
    """A joint named in an arm assignment, a lock or a limit override is wrong."""

    def __init__(self, joint: str, source: str, reason: str):
        self.joint = joint
        self.source = source
        self.reason = reason
        super().__init__(f"joint '{joint}' in {source}: {reason}")


class ArmError(InputError):
    """An arm assignment is wrong as a whole (for example an arm with no joints)."""

    def __init__(self, arm: str, source: str, reason: str):
        self.arm = arm
        self.source = source
        self.reason = reason
        super().__init__(f"arm '{arm}' of {source}: {reason}")


class TrajectoryError(InputError):
    """A mission trajectory that cannot be built (bad CSV, unreachable goal, ...)."""


class InfeasibleLimitsError(InputError):
    """Limits that no plan can meet (for example an initial configuration outside them)."""


class SolverError(BalanceOptError):
    """The solver did not converge. CLI exit code 1.

    Attributes:
        status: the solver's own return status.
        result: the best iterate, as a result object, so that it can still be written.
    """

    def __init__(self, message: str, status: str, result=None):
        self.status = status
        self.result = result
        super().__init__(message)


class DivergenceError(BalanceOptError):
    """A forward-dynamics simulation whose state left every sane bound: it was stopped there.

    Attributes:
        t: the time at which it was stopped [s].
        reason: which bound it left.
    """

    def __init__(self, t: float, reason: str):
        self.t = t
        self.reason = reason
        super().__init__(f"the forward-dynamics simulation diverged at t = {t:.4g} s: {reason}")
