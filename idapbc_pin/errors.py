"""User-facing errors: each message names the problem and the fix."""

from __future__ import annotations

__all__ = ["IdapbcError", "NotAnEquilibriumError"]


class IdapbcError(ValueError):
    """Bad input from the user (file, joint name, target, config).

    The message is one line that says what is wrong and how to fix it; the CLI prints it and exits
    with status 2, never with a traceback.
    """


class NotAnEquilibriumError(IdapbcError):
    """The target x* is not an assignable equilibrium: g⊥ f(x*) ≠ 0.

    `residuals` maps each offending row (an unactuated joint, or ``q̇_<joint>``) to its residual
    torque or force (N·m or N).
    """

    def __init__(self, message: str, residuals: dict[str, float]):
        super().__init__(message)
        self.residuals = residuals
