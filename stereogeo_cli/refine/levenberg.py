"""The one Levenberg–Marquardt loop of the package: damping, step rejection, stopping and covariance.

Every least-squares fit of the calibration runs through :func:`levenberg_marquardt`: the per-camera
refiner (``refine/lm.py``), the relative pose's joint refinement (``fuse/pose.py``) and the Manhattan frame
of the vanishing points (``refine/manhattan.py``). The training loss's differentiable refiner
(``refine/torch_twin.py``) is the same loop unrolled over a batch, step for step.

A problem gives three functions of its parameters x (any type the problem likes: an array, a tuple, a
named state):

- ``cost(x)``: the scalar the fit minimises (robust losses included);
- ``normal_equations(x)``: (H, g), the Gauss–Newton Hessian (with IRLS weights for a robust loss) and the
  gradient, in the coordinates of a step δ; or (H, g, D), with D the damping's diagonal where diag(H) is
  not the scale to damp by;
- ``retract(x, δ)``: x moved by δ (a plain sum, or a step on a manifold: the sphere, rotations).

The step solves (H + λ·D)·δ = −g, D = diag(H) by default (Marquardt's scaling), so the damping does not
depend on the units of the parameters. A step is kept only where it lowers the cost; then λ shrinks ×0.1
(floored), otherwise it grows ×10 and the step is tried again from the same point. The fit stops after
``max_iterations`` tries (kept or not), when a kept step lowers the cost by less than
``relative_tolerance`` of it, when a kept step is shorter than ``step_tolerance``, or when λ passes
``lambda_max`` (no step lowers the cost: a minimum to numerical precision).

A robust loss's IRLS Hessian counts, for a residual in the loss's outer part, a curvature along the
residual that the loss does not have. Far from the minimum that is what keeps a step safe (the IRLS cost
lies above the robust one); near it, where many residuals stay in the outer part for good, it shortens every
step by a fixed share and the fit creeps. With ``curvature_switch`` set, ``normal_equations(x, near)`` is
called with ``near`` True once a kept step has lowered the cost by less than that share of it: from there
the problem gives the Hessian with the loss's own curvature (Newton's steps on the robust cost).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

LAMBDA_DOWN = 0.1  # λ after a kept step
LAMBDA_UP = 10.0  # λ after a rejected one
LAMBDA_FLOOR = 1e-10
DIAGONAL_FLOOR = 1e-12  # keeps the damping positive along a direction the data do not see


@dataclass(frozen=True)
class Settings:
    """The numbers of one fit; the schedule is the module's."""

    max_iterations: int = 30
    lambda_init: float = 0.1
    lambda_max: float = 1e8
    relative_tolerance: float = 1e-7
    step_tolerance: float = 0.0
    curvature_switch: float | None = None  # module docstring


@dataclass
class Result:
    """Where a fit ended: the parameters, their cost, and H and g there (``H``, ``gradient``: computed on
    first use where the fit stopped on a kept step, as most callers need neither)."""

    x: Any
    cost: float
    iterations: int  # steps tried, kept or not
    converged: bool
    history: list[float]  # the cost at the start and after every kept step
    equations: Callable[[], tuple[np.ndarray, np.ndarray]] = field(repr=False)  # (H, g) at x

    @cached_property
    def _at_end(self) -> tuple[np.ndarray, np.ndarray]:
        return self.equations()

    @property
    def H(self) -> np.ndarray:
        return self._at_end[0]

    @property
    def gradient(self) -> np.ndarray:
        return self._at_end[1]


def damped_step(H: np.ndarray, g: np.ndarray, lam: float, damping: np.ndarray | None = None) -> np.ndarray:
    """δ solving (H + λ·(D + ε))·δ = −g, D = ``damping`` (default diag(H)); raises
    ``np.linalg.LinAlgError`` where singular."""
    D = np.diag(H) if damping is None else damping
    return -np.linalg.solve(H + lam * np.diag(D + DIAGONAL_FLOOR), g)


def levenberg_marquardt(
    x0: Any,
    cost: Callable[[Any], float],
    normal_equations: Callable[[Any], tuple[np.ndarray, np.ndarray]],
    retract: Callable[[Any, np.ndarray], Any],
    settings: Settings = Settings(),
    free: np.ndarray | None = None,
) -> Result:
    """Minimise ``cost`` from ``x0`` (module docstring). ``free``: a boolean mask of the step's coordinates
    that move (the others are held: their rows and columns are left out of the solve and their step is 0);
    default all. ``H`` and ``gradient`` in the result are the full ones at the final x."""
    switch = settings.curvature_switch
    near = False

    def equations(x):
        found = normal_equations(x) if switch is None else normal_equations(x, near)
        return found[0], found[1], (found[2] if len(found) > 2 else None)

    x, current = x0, float(cost(x0))
    H, g, D = equations(x)
    at_end = (H, g)  # the normal equations at x, where they have been computed there
    n = len(g)
    free = np.ones(n, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    every = bool(free.all())
    history, lam, iterations, converged = [current], settings.lambda_init, 0, False
    while iterations < settings.max_iterations and free.any():
        iterations += 1
        try:
            step_free = damped_step(
                H if every else H[np.ix_(free, free)], g[free], lam, None if D is None else D[free]
            )
        except np.linalg.LinAlgError:
            break
        step = np.zeros(n)
        step[free] = step_free
        candidate = retract(x, step)
        new = float(cost(candidate))
        if new < current:
            decrease = current - new
            x, current = candidate, new
            history.append(current)
            lam = max(lam * LAMBDA_DOWN, LAMBDA_FLOOR)
            near = near or (switch is not None and decrease <= switch * (current + decrease))
            if (
                decrease <= settings.relative_tolerance * (current + decrease)
                or current < 1e-24
                or np.linalg.norm(step) < settings.step_tolerance
            ):
                converged, at_end = True, None
                break
            H, g, D = equations(x)
            at_end = (H, g)
        else:
            lam *= LAMBDA_UP
            if lam > settings.lambda_max:
                converged = True
                break
    end = x
    return Result(
        x, current, iterations, converged, history,
        (lambda: at_end) if at_end is not None else (lambda: equations(end)[:2]),
    )  # fmt: skip


def covariance(bread: np.ndarray, meat: np.ndarray | None = None, free: np.ndarray | None = None):
    """The covariance of a fit's parameters: ``bread``⁻¹ (the inverse Hessian, for residuals in units of
    their sigmas) or, with ``meat`` = Σ gₙgₙᵀ over the observations' gradients, the robust sandwich
    bread⁻¹·meat·bread⁻¹ of an M-estimator, which stays honest where the loss and the weights make the
    residuals unequal. Held coordinates (``free`` False) get 0; a singular bread gives inf on the free ones.
    """
    n = len(bread)
    free = np.ones(n, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    cov = np.zeros((n, n))
    if not free.any():
        return cov
    sel = np.ix_(free, free)
    try:
        inverse = np.linalg.inv(bread[sel])
    except np.linalg.LinAlgError:
        cov[sel] = np.inf
        return cov
    cov[sel] = inverse if meat is None else inverse @ meat[sel] @ inverse
    return cov
