"""Task-priority inverse kinematics: the solver that stacks the arm controller's tasks
(arm_control.ArmController, the paper's arm controller).

    qdot = J1+ K1 e1 + N1 (J2 N1)+ (K2 e2 - J2 qdot1) + ... + N1..n-1 (Jn N1..n-1)+ (...)

Each task is solved in the null space of the augmented Jacobian of the tasks above it, so a
lower task never disturbs a higher one; the pseudo-inverse is damped near singularities.
Safety constraints (joint limits, clearance from obstacles) are inequalities in the
velocity-damper form hdot >= -k (h - h_min): they join the top of the stack only while the
solution without them would break them (set-based task priority), so they cost the mission
nothing while it is safe, and they rank above it when it is not.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Task:
    """Rows of a task: J xdot = velocity, in the decision variables x."""

    name: str
    jacobian: np.ndarray  # (m, n)
    velocity: np.ndarray  # (m,)


@dataclass(frozen=True)
class Constraints:
    """Rows h(x) >= minimum, each enforced as the velocity damper hdot >= -k (h - minimum)."""

    names: tuple[str, ...]
    gradients: np.ndarray  # (c, n) dh/dx
    values: np.ndarray  # (c,)
    minimums: np.ndarray  # (c,)

    def rates(self, k: float) -> np.ndarray:
        return -k * (self.values - self.minimums)


def damped_inverse(
    u: np.ndarray, s: np.ndarray, vt: np.ndarray, damping: float, threshold: float
) -> np.ndarray:
    """Pseudo-inverse, from a thin SVD, with damping that grows as the smallest singular value
    falls below `threshold`, up to `damping` at a singularity (Nakamura and Hanafusa; Maciejewski)."""
    smallest = float(s[-1]) if s.size else 0.0
    damping2 = damping**2 * (1.0 - (smallest / threshold) ** 2) if smallest < threshold else 0.0
    denominator = s**2 + damping2  # descending, as s
    if s.size and denominator[-1] > 1e-300:  # none is zero: no need to guard the division
        return (vt.T * (s / denominator)) @ u.T
    inverse = np.divide(s, denominator, out=np.zeros_like(s), where=denominator > 1e-300)
    return (vt.T * inverse) @ u.T


def damped_pinv(jacobian: np.ndarray, damping: float, threshold: float) -> np.ndarray:
    """`damped_inverse` of `jacobian`."""
    return damped_inverse(*np.linalg.svd(jacobian, full_matrices=False), damping, threshold)


def null_projector(s: np.ndarray, vt: np.ndarray) -> np.ndarray:
    """The orthogonal projector onto the null space of a matrix, from its thin SVD (singular values
    descending); those up to 1e-10 times the largest count as zero (as numpy's pinv with that rcond)."""
    kept = vt[: np.count_nonzero(s > 1e-10 * s[0])]
    return np.eye(vt.shape[1]) - kept.T @ kept


def solve(tasks: Sequence[Task], n: int, damping: float, threshold: float) -> list[np.ndarray]:
    """Each task's contribution to xdot, in priority order; xdot is their sum. The first task's
    SVD serves twice: its pseudo-inverse and the null space the second task works in; the last
    task's null space is never formed."""
    if not tasks:
        return []
    u, s, vt = np.linalg.svd(tasks[0].jacobian, full_matrices=False)
    xdot = damped_inverse(u, s, vt, damping, threshold) @ tasks[0].velocity
    contributions = [xdot]
    for i, task in enumerate(tasks[1:], start=1):
        if i > 1:  # the augmented Jacobian of the tasks above
            _, s, vt = np.linalg.svd(np.vstack([t.jacobian for t in tasks[:i]]), full_matrices=False)
        projector = null_projector(s, vt)
        u, s, vt = np.linalg.svd(task.jacobian @ projector, full_matrices=False)
        inverse = damped_inverse(u, s, vt, damping, threshold)
        step = projector @ (inverse @ (task.velocity - task.jacobian @ xdot))
        xdot = xdot + step
        contributions.append(step)
    return contributions


def solve_constrained(
    constraints: Constraints, tasks: Sequence[Task], n: int, k: float, damping: float, threshold: float
) -> tuple[np.ndarray, list[int], list[np.ndarray]]:
    """Set-based task priority: the constraints that the solution would break join the top
    of the stack, the worst first, until none is broken. Returns xdot, the active constraints'
    indices and every task's contribution (the active constraints' first)."""
    rates = constraints.rates(k)
    bound = rates - 1e-12  # broken below
    active: list[int] = []
    while True:
        above = [
            Task(constraints.names[i], constraints.gradients[i : i + 1], rates[i : i + 1]) for i in active
        ]
        contributions = solve(above + list(tasks), n, damping, threshold)
        xdot = sum(contributions, np.zeros(n))
        along = constraints.gradients @ xdot
        broken = along < bound
        if active:
            broken[active] = False
        if not broken.any():
            return xdot, active, contributions
        active.append(int(np.argmin(np.where(broken, along - rates, np.inf))))
