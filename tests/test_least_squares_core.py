"""The least-squares core (veil.fitting.least_squares, docs/fitting.md "How a fit works"):
the Levenberg-Marquardt iteration of the single fits on problems whose answer is known -
linear least squares in closed form, an optimum outside the box, a limit on evaluations, a
badly scaled Rosenbrock valley, an approximate (frozen) Jacobian - bit-for-bit
determinism, the stopping rule's promise (within ``tol`` standard errors of the optimum),
and the one step the per-pixel maps share (numpy and JAX alike)."""

from __future__ import annotations

import numpy as np
import pytest

from veil.fitting import least_squares as lsq
from veil.fitting import solver

INF = np.full(2, np.inf)


def linear(n=40, seed=0, sigma=0.1):
    """(X, y, exact solution, standard errors) of a weighted straight-line fit y = X p."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 3.0, n)
    x = np.stack([np.ones(n), t], axis=1) / sigma
    y = (x @ np.array([1.0, -2.0])) + rng.normal(size=n)
    exact = np.linalg.lstsq(x, y, rcond=None)[0]
    se = np.sqrt(np.diag(np.linalg.inv(x.T @ x)))
    return x, y, exact, se


def rosenbrock(scale=(1.0, 1.0)):
    """Rosenbrock's valley as least squares in parameters q = p / scale (p the usual ones)."""
    s = np.asarray(scale, dtype=float)

    def fun(q):
        p = q * s
        return np.array([10.0 * (p[1] - p[0] ** 2), 1.0 - p[0]])

    def jac(q):
        p = q * s
        return np.array([[-20.0 * p[0], 10.0], [-1.0, 0.0]]) * s[None, :]

    return fun, jac, np.array([-1.2, 1.0]) / s


def test_linear_least_squares_is_solved_exactly_in_a_few_iterations():
    x, y, exact, se = linear()
    fit = lsq.levenberg_marquardt(lambda p: x @ p - y, lambda p: x, np.zeros(2), -INF, INF,
                                  tol=1e-6)
    assert fit.status == 1 and "Gauss-Newton step" in fit.message
    assert np.all(np.abs(fit.p - exact) <= 1e-6 * se)
    r = x @ exact - y
    assert fit.cost == pytest.approx(0.5 * r @ r, rel=1e-12)
    assert np.array_equal(fit.residuals, x @ fit.p - y)
    # one damped step lands within the damping's 1e-4 of the optimum, one more on it
    assert fit.nfev <= 4 and fit.njev == fit.nfev


def test_an_optimum_outside_the_box_ends_on_the_bound():
    x, y, exact, se = linear()
    hi = np.array([np.inf, exact[1] - 5 * se[1]])  # the slope's optimum lies above the box
    fit = lsq.levenberg_marquardt(lambda p: x @ p - y, lambda p: x, np.zeros(2), -INF, hi,
                                  tol=1e-6)
    assert fit.status == 1
    assert fit.p[1] == hi[1]  # on it exactly, held there
    # the intercept is the constrained optimum: least squares with the slope at the bound
    intercept = np.linalg.lstsq(x[:, :1], y - x[:, 1] * hi[1], rcond=None)[0][0]
    assert fit.p[0] == pytest.approx(intercept, abs=1e-6 * se[0])
    low, high = lsq.at_bounds(fit.p, -INF, hi, 1e-9)
    assert not low.any() and list(high) == [False, True]


def test_the_evaluation_limit_stops_with_a_status_of_zero():
    fun, jac, q0 = rosenbrock()
    fit = lsq.levenberg_marquardt(fun, jac, q0, -INF, INF, tol=1e-8, max_nfev=3)
    assert fit.status == 0 and fit.nfev == 3
    assert "maximum number of function evaluations (3)" in fit.message
    # the point returned is the best evaluated, with its residuals
    assert np.array_equal(fit.residuals, fun(fit.p)) and fit.cost <= 0.5 * fun(q0) @ fun(q0)


@pytest.mark.parametrize("scale", [(1.0, 1.0), (1e4, 1e-4)])
def test_a_badly_scaled_rosenbrock_valley(scale):
    fun, jac, q0 = rosenbrock(scale)
    fit = lsq.levenberg_marquardt(fun, jac, q0, -INF, INF, tol=1e-8)
    assert fit.status == 1
    assert np.allclose(fit.p * np.asarray(scale), 1.0, rtol=1e-8, atol=0)
    assert fit.nfev < 60


def test_the_same_problem_gives_the_same_bits():
    fun, jac, q0 = rosenbrock((1e4, 1e-4))
    a = lsq.levenberg_marquardt(fun, jac, q0, -INF, INF, tol=1e-8)
    b = lsq.levenberg_marquardt(fun, jac, q0.copy(), -INF, INF, tol=1e-8)
    assert a.p.tobytes() == b.p.tobytes() and a.cost == b.cost
    assert (a.nfev, a.njev, a.status) == (b.nfev, b.njev, b.status)


def exponential(seed=1, n=60):
    """A nonlinear weighted fit: y = A exp(-k t) + noise, parameters (log A, log k)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, n)
    sigma = 0.02
    y = 2.0 * np.exp(-0.7 * t) + sigma * rng.normal(size=n)

    def fun(u):
        return (np.exp(u[0]) * np.exp(-np.exp(u[1]) * t) - y) / sigma

    def jac(u):
        m = np.exp(u[0]) * np.exp(-np.exp(u[1]) * t)
        return np.stack([m, -m * t * np.exp(u[1])], axis=1) / sigma

    return fun, jac, np.array([np.log(0.5), np.log(3.0)])


@pytest.mark.parametrize("tol", [1e-1, 1e-2, 1e-3])
def test_a_stopped_iteration_is_within_tol_standard_errors_of_the_optimum(tol):
    fun, jac, u0 = exponential()
    best = lsq.levenberg_marquardt(fun, jac, u0, -INF, INF, tol=1e-9)
    fit = lsq.levenberg_marquardt(fun, jac, u0, -INF, INF, tol=tol)
    cov, full = lsq.covariance(jac(best.p))
    assert full and fit.status == 1 and best.status > 0
    assert np.all(np.abs(fit.p - best.p) <= tol * np.sqrt(np.diag(cov)))
    assert fit.nfev <= best.nfev


def test_unweighted_data_measure_steps_by_their_scatter():
    """Data without weights: the same iterations whatever their units."""
    fun, jac, u0 = exponential()
    runs = []
    for factor in (1.0, 1e3):
        def f(u, factor=factor):
            return fun(u) * factor

        def j(u, factor=factor):
            return jac(u) * factor

        runs.append(lsq.levenberg_marquardt(f, j, u0, -INF, INF, tol=1e-3, dof=58,
                                            weighted=False))
    a, b = runs
    assert a.status == b.status == 1 and (a.nfev, a.njev) == (b.nfev, b.njev)
    assert np.allclose(a.p, b.p, rtol=0, atol=1e-12)


def test_a_frozen_jacobian_converges_to_its_own_floor_without_wasting_evaluations():
    """The polish's chord method: a Jacobian 1 % off (frozen) cannot bring the Gauss-Newton
    step below its own error; the iterations still end converged, near the optimum."""
    x, y, exact, se = linear(sigma=0.02)
    y = y + 30.0 * np.sin(np.arange(y.size))  # a model that misses the data: large residuals
    exact = np.linalg.lstsq(x, y, rcond=None)[0]
    se = se * np.sqrt(np.sum((x @ exact - y) ** 2) / (y.size - 2))
    off = x * (1.0 + 0.01 * np.random.default_rng(3).normal(size=x.shape))
    fit = lsq.levenberg_marquardt(lambda p: x @ p - y, lambda p: off, exact + 3 * se,
                                  -INF, INF, tol=1e-3, dof=y.size - 2)
    assert fit.status > 0 and fit.nfev <= 10
    assert np.all(np.abs(fit.p - exact) <= 0.05 * se)


def test_residuals_that_are_not_finite():
    x, y, _, _ = linear()
    fit = lsq.levenberg_marquardt(lambda p: np.full(y.size, np.nan), lambda p: x, np.zeros(2),
                                  -INF, INF, tol=1e-3)
    assert fit.status == -2 and fit.nfev == 1 and "not finite" in fit.message
    # a region where the model is not defined is stepped around, not into
    fun, jac, q0 = rosenbrock()

    def guarded(q):
        return np.full(2, np.nan) if q[1] > 1.5 else fun(q)

    fit = lsq.levenberg_marquardt(guarded, jac, q0, -INF, INF, tol=1e-8)
    assert fit.status == 1 and np.allclose(fit.p, 1.0, rtol=1e-8, atol=0)


def test_numpy_and_jax_take_the_same_step():
    """The maps' batched iterations and the single fits share lsq.lm_step, held parameters
    and damping scale included."""
    from veil._jax import jnp

    rng = np.random.default_rng(4)
    jm = rng.normal(size=(20, 3))
    a, g = jm.T @ jm, jm.T @ rng.normal(size=20)
    p = np.array([0.5, 0.0, 2.0])
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 2.0])
    g[1], g[2] = -abs(g[1]), abs(g[2])  # parameters 1 and 2 pushed out of the box: held
    scale = np.diag(a) * 2.0
    for extra in ((), (scale,)):
        trial, dec = lsq.lm_step(p, a, g, 1e-3, lo, hi, np, *extra)
        trial_j, dec_j = lsq.lm_step(*map(jnp.asarray, (p, a, g)), 1e-3, jnp.asarray(lo),
                                     jnp.asarray(hi), jnp, *map(jnp.asarray, extra))
        assert np.allclose(trial, np.asarray(trial_j), rtol=1e-13, atol=1e-15)
        assert float(dec) == pytest.approx(float(dec_j), rel=1e-13)
        assert trial[1] == 0.0 and trial[2] == 2.0  # held ones stay
        # the free parameter's step solves its own damped equation alone
        d = scale[0] if extra else a[0, 0]
        assert trial[0] - p[0] == pytest.approx(g[0] / (a[0, 0] + 1e-3 * d), rel=1e-12)
        assert float(dec) == pytest.approx(g[0] ** 2 / a[0, 0], rel=1e-12)



@pytest.mark.parametrize("n", [lsq.UNROLLED_MAX + 1, 7, 9])
def test_the_looped_ldl_of_a_larger_matrix_solves_it(n):
    """With JAX, a matrix of more than UNROLLED_MAX rows is factored by a loop over its
    columns (the maps over channels: 7 parameters): its solves, inverse and rank against
    numpy's dense algebra, for one and several right-hand sides, and the same step as the
    unrolled factorization of the single fits."""
    from veil._jax import jax, jnp

    rng = np.random.default_rng(n)
    jm = rng.normal(size=(n + 4, n)) * np.exp(rng.normal(size=n))  # columns of many scales
    a, b = jm.T @ jm, rng.normal(size=(n, 3))
    low, piv = lsq.ldl(jnp.asarray(a), jnp)
    assert not isinstance(low, list)  # the loop, not the unrolled code
    for rhs in (b[:, 0], b):
        x = np.asarray(lsq.ldl_solve(low, piv, jnp.asarray(rhs), jnp))
        assert np.allclose(x, np.linalg.solve(a, rhs), rtol=1e-9, atol=0)
    cov, full = lsq.normal_covariance(jnp.asarray(a), True, jnp)
    assert bool(full) and np.allclose(np.asarray(cov), np.linalg.inv(a), rtol=1e-9, atol=0)
    singular = a.copy()
    singular[:, -1], singular[-1, :] = singular[:, 0], singular[0, :]  # two equal columns
    assert not bool(lsq.normal_covariance(jnp.asarray(singular), True, jnp)[1])
    # the step of the maps' batched iterations (vmapped) is the single fits' numpy step
    g, p = jm.T @ rng.normal(size=n + 4), np.full(n, 0.5)
    lo, hi = np.zeros(n), np.ones(n)
    trial, dec = lsq.lm_step(p, a, g, 1e-3, lo, hi, np)
    batched = jax.vmap(lambda aa: lsq.lm_step(jnp.asarray(p), aa, jnp.asarray(g), 1e-3,
                                              jnp.asarray(lo), jnp.asarray(hi), jnp))
    trial_j, dec_j = batched(jnp.stack([jnp.asarray(a)] * 2))
    assert np.allclose(np.asarray(trial_j), trial, rtol=1e-10, atol=1e-14)
    assert np.allclose(np.asarray(dec_j), dec, rtol=1e-10)

# --------------------------------------------------------------------------------------
# solve(): the single fits' use of the core, on a problem shaped like veil's Problem
# --------------------------------------------------------------------------------------
class Line:
    """y = a + b t, weighted; ``a`` within [0, a_max] (plain coordinates), ``b`` within
    [-100, 100]:
    what :func:`veil.fitting.solver.solve` reads of a :class:`veil.fitting.problem.Problem`."""

    def __init__(self, a_max=100.0, n=30, seed=0):
        rng = np.random.default_rng(seed)
        self.t = np.linspace(0.0, 1.0, n)
        self.w = np.full(n, 10.0)
        self.y = 1.0 + 2.0 * self.t + rng.normal(size=n) / self.w
        self.values = np.array([0.5, 0.5])
        self.free = np.array([True, True])
        self.free_names = ["a", "b"]
        self.weighted, self.n_points, self.n_free = True, n, 2
        self.a_max = a_max
        self.remembered = None

    def to_u(self, x):
        return np.asarray(x, dtype=float)[self.free]

    def to_x(self, u, base=None):
        return np.asarray(u, dtype=float).copy(), np.ones(len(u))

    def bounds(self, u0):
        return np.array([0.0, -100.0]), np.array([self.a_max, 100.0])

    def model_values(self, x, accuracy="fast"):
        return x[0] + x[1] * self.t

    def value_and_jacobian(self, x, accuracy, columns):
        return self.model_values(x), np.stack([np.ones_like(self.t), self.t], axis=1)

    def prior_rows(self, x):
        return np.zeros(0), np.zeros((0, 2))

    def remember(self, x, accuracy, values):
        self.remembered = (x, values)


def test_solve_reports_the_solution_and_the_bound():
    free = Line()
    ticks = []
    sol = solver.solve(free, free.values, on_eval=lambda: ticks.append(1))
    assert sol.status == 1 and sol.at_bound == [] and sol.at_lower == []
    assert len(ticks) == sol.nfev and sol.njev >= 1
    r = (free.model_values(sol.x) - free.y) * free.w
    assert sol.cost == pytest.approx(0.5 * r @ r, rel=1e-12)
    x, values = free.remembered  # the solution's values, kept for the next call
    assert np.array_equal(x, sol.x) and np.array_equal(values, free.model_values(sol.x))
    boxed = Line(a_max=0.8)  # the intercept's optimum (about 1) is outside
    sol = solver.solve(boxed, boxed.values)
    assert sol.status == 1 and sol.x[0] == 0.8 and sol.at_bound == ["a"] and not sol.at_lower
    floor = Line()
    floor.y = -1.0 + 2.0 * floor.t  # a negative intercept: on the floor
    sol = solver.solve(floor, floor.values)
    assert sol.x[0] == 0.0 and sol.at_bound == ["a"] and sol.at_lower == ["a"]


def test_solve_stops_at_max_nfev_and_says_so():
    line = Line()
    sol = solver.solve(line, line.values, max_nfev=1)
    assert sol.status <= 0 and sol.nfev == 1
    assert "maximum number of function evaluations" in sol.message


def test_solve_with_a_frozen_jacobian():
    """The polish's chord method: the Jacobian at ``jacobian_at``, whatever the iterate."""
    line = Line()
    seen = []
    jacobian = line.value_and_jacobian

    def spy(x, accuracy, columns):
        seen.append(np.array(x))
        return jacobian(x, accuracy, columns)

    line.value_and_jacobian = spy
    at = np.array([0.9, 2.1])
    sol = solver.solve(line, line.values, jacobian_at=at, tol=solver.TOL_POLISH)
    assert sol.status > 0 and all(np.array_equal(s, at) for s in seen) and seen


def test_the_damping_follows_the_gain_and_the_room_to_the_bounds():
    """lm_accept: a step taken lowers the damping when the model predicted its decrease well,
    keeps it when fairly, raises it when poorly; a step not taken raises it. damping_scale:
    the largest diagonal, over each parameter's room to the bound it is pushed to (relative
    to their geometric mean, in equilibrated units)."""
    lam = 1e-3
    for actual, predicted, taken, factor in ((0.9, 1.0, True, lsq.DAMPING_DOWN),
                                             (0.5, 1.0, True, 1.0),
                                             (0.1, 1.0, True, lsq.DAMPING_UP),
                                             (-1.0, 1.0, False, lsq.DAMPING_UP),
                                             (0.5, 0.0, True, lsq.DAMPING_UP)):
        better, new = lsq.lm_accept(10.0, 10.0 - actual, lam, False, np, predicted)
        assert bool(better) == taken and float(new) == pytest.approx(lam * factor)
    # without a prediction (the maps): down after any step taken
    assert float(lsq.lm_accept(10.0, 9.99, lam, False, np)[1]) == lam * lsq.DAMPING_DOWN
    largest = np.array([4.0, 4.0, 9.0])
    lo, hi = np.array([0.0, 0.0, -np.inf]), np.array([10.0, 10.0, np.inf])
    p, g = np.array([5.0, 9.0, 0.0]), np.array([1.0, 1.0, 1.0])  # pushed up: room 5, 1, inf
    scale = lsq.damping_scale(largest, p, g, lo, hi)
    rooms = np.array([5.0, 1.0]) * 2.0  # in equilibrated units (column norm 2)
    mean = np.sqrt(rooms[0] * rooms[1])
    assert np.allclose(scale, [4.0 * mean / rooms[0], 4.0 * mean / rooms[1], 9.0])
    assert scale[1] > scale[0]  # closer to its bound: damped more
    same = lsq.damping_scale(largest, np.array([5.0, 5.0, 0.0]), g, lo, hi)
    assert np.allclose(same, largest)


def test_a_start_far_off_in_log_coordinates():
    """A exp(-k t) + c from A 17 times and k 16 times off, in log A and log k within wide
    boxes: the fit reaches the optimum."""
    t = np.linspace(0.0, 5.0, 50)
    y = 3.0 * np.exp(-0.8 * t) + 0.5

    def fun(u):
        return np.exp(u[0]) * np.exp(-np.exp(u[1]) * t) + u[2] - y

    def jac(u):
        m = np.exp(u[0]) * np.exp(-np.exp(u[1]) * t)
        return np.stack([m, -m * t * np.exp(u[1]), np.ones_like(t)], axis=1)

    u0 = np.array([np.log(50.0), np.log(0.05), 5.0])
    lo, hi = u0 - np.array([40.0, 40.0, 100.0]), u0 + np.array([40.0, 40.0, 100.0])
    fit = lsq.levenberg_marquardt(fun, jac, u0, lo, hi, tol=1e-6)
    assert fit.status == 1
    assert np.allclose([np.exp(fit.p[0]), np.exp(fit.p[1]), fit.p[2]], [3.0, 0.8, 0.5],
                       rtol=1e-6)


def test_a_jacobian_frozen_far_from_the_optimum_still_ends_converged():
    """The sigma-point refits' chord method with a Jacobian taken where the model differs: the
    steps creep (the model over-predicts each decrease), and the run ends when a step lowers
    the cost by less than one of ``tol`` standard errors would - not at the evaluation
    limit."""
    fun, jac, u0 = exponential()
    best = lsq.levenberg_marquardt(fun, jac, u0, -INF, INF, tol=1e-9)
    start = best.p + np.array([0.3, -0.3])
    frozen = jac(start)
    fit = lsq.levenberg_marquardt(fun, lambda u: frozen, start, -INF, INF, tol=1e-2,
                                  max_nfev=50, exact=False)
    cov, _ = lsq.covariance(jac(best.p))
    assert fit.status > 0 and fit.nfev < 50, fit
    assert np.all(np.abs(fit.p - best.p) <= 0.1 * np.sqrt(np.diag(cov)))


def test_every_start_of_a_clear_water_fit_finds_the_optimum():
    """Step 0 on the paper's session without sigmas: the third start lies far off (its
    specular part too large by orders). With the damping scaled by J^T J's current diagonal a
    step drove P_d to the floor of its range, where its column vanished, and the run ended
    there (lsq.damping_scale: the largest column met, the room to the bounds)."""
    import veil

    table = veil.simulate(veil.BRDF2, None, seed=0).drop(columns="sigma")
    fit = veil.fit_reference(table)
    runs = fit.stats["runs"]
    assert len(runs) == 3 and all(r["status"] > 0 for r in runs)
    costs = [r["cost"] for r in runs]
    assert max(costs) - min(costs) <= 1e-9 * min(costs)
