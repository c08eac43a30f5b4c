"""The package's one Levenberg–Marquardt loop: it finds least-squares minima, keeps only steps that lower the
cost, holds what it is told to hold, and gives the covariance of the fit."""

import numpy as np
import pytest

from stereogeo_cli.refine.levenberg import Settings, covariance, levenberg_marquardt


def _rosenbrock():
    """Residuals (1 - x, 10·(y - x²)): a curved valley whose minimum is (1, 1), cost 0."""

    def residuals(p):
        return np.array([1.0 - p[0], 10.0 * (p[1] - p[0] ** 2)])

    def jacobian(p):
        return np.array([[-1.0, 0.0], [-20.0 * p[0], 10.0]])

    def cost(p):
        r = residuals(p)
        return float(r @ r)

    def normal_equations(p):
        J, r = jacobian(p), residuals(p)
        return J.T @ J, J.T @ r

    return cost, normal_equations


def test_it_walks_the_curved_valley_to_the_minimum_with_every_kept_step_lowering_the_cost():
    cost, normal_equations = _rosenbrock()
    start = np.array([-1.2, 1.0])
    fit = levenberg_marquardt(start, cost, normal_equations, np.add, Settings(max_iterations=200))
    assert fit.converged
    np.testing.assert_allclose(fit.x, [1.0, 1.0], atol=1e-6)
    assert fit.cost < 1e-12
    assert all(b < a for a, b in zip(fit.history, fit.history[1:], strict=False))
    assert fit.history[0] == pytest.approx(cost(start))
    # H and g are those at the end point
    H, g = normal_equations(fit.x)
    np.testing.assert_allclose(fit.H, H)
    np.testing.assert_allclose(fit.gradient, g)


def test_a_held_coordinate_does_not_move_and_the_free_one_finds_its_own_minimum():
    cost, normal_equations = _rosenbrock()
    fit = levenberg_marquardt(
        np.array([0.5, 2.0]), cost, normal_equations, np.add, Settings(max_iterations=100), free=[True, False]
    )
    assert fit.x[1] == 2.0
    # with y = 2 held, the cost (1 - x)² + 100·(2 - x²)² is least where 400x³ - 798x - 2 = 0
    root = max(r.real for r in np.roots([400.0, 0.0, -798.0, -2.0]) if abs(r.imag) < 1e-12)
    assert fit.x[0] == pytest.approx(root, abs=1e-6)


def test_a_cost_that_no_step_lowers_stops_where_it_started():
    """A gradient that points the wrong way (a bug in a problem, or a minimum to numerical precision): every
    step is rejected, the damping grows past its limit, and the start is returned unchanged."""
    fit = levenberg_marquardt(
        np.array([1.0]),
        lambda p: float(p[0] ** 2),
        lambda p: (np.eye(1), -p),  # the negative of the true gradient
        np.add,
        Settings(max_iterations=100, lambda_max=1e4),
    )
    assert fit.x[0] == 1.0 and fit.history == [1.0]
    assert fit.converged and fit.iterations == 6  # λ 0.1 → 1 → … → 1e5 > 1e4


def test_the_iteration_limit_counts_every_step_tried():
    cost, normal_equations = _rosenbrock()
    fit = levenberg_marquardt(
        np.array([-1.2, 1.0]), cost, normal_equations, np.add, Settings(max_iterations=3)
    )
    assert fit.iterations == 3 and not fit.converged


def test_covariance_is_the_inverse_or_the_sandwich_with_held_coordinates_zero():
    A = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    np.testing.assert_allclose(covariance(A), np.linalg.inv(A))
    meat = np.diag([1.0, 2.0, 3.0])
    np.testing.assert_allclose(covariance(A, meat), np.linalg.inv(A) @ meat @ np.linalg.inv(A))
    free = np.array([True, False, True])
    held = covariance(A, free=free)
    assert np.all(held[1] == 0) and np.all(held[:, 1] == 0)
    np.testing.assert_allclose(held[np.ix_(free, free)], np.linalg.inv(A[np.ix_(free, free)]))
    singular = covariance(np.zeros((2, 2)))
    assert np.all(np.isinf(singular))


def test_the_curvature_switch_turns_on_once_steps_lower_the_cost_little():
    """``near`` is False until a kept step lowers the cost by less than the switch's share, True after."""
    cost, normal_equations = _rosenbrock()
    seen = []

    def equations(x, near):
        seen.append((cost(x), near))
        return normal_equations(x)

    fit = levenberg_marquardt(
        np.array([-1.2, 1.0]), cost, equations, np.add, Settings(max_iterations=200, curvature_switch=0.1)
    )
    assert fit.converged and fit.cost < 1e-10
    flags = [near for _, near in seen]
    assert flags[0] is False and flags[-1] is True
    first = flags.index(True)
    assert all(flags[first:])  # it stays on
    before, at = seen[first - 1][0], seen[first][0]
    assert before - at <= 0.1 * before  # the step that turned it on lowered the cost by less than a tenth
    assert all(a - b > 0.1 * a for (a, _), (b, _) in zip(seen[: first - 1], seen[1:first], strict=True))
