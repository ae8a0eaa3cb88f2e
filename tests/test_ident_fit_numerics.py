"""The fit's numerics around the simulations (fit.py) give, bit for bit, what the plain
formulas give: the normal equations, the finite-difference Jacobian blocks, the residual's
autocovariances, the start screen and the covariance (and the LM's damped system, a change
measured and not kept: docs/identification-speed-log.md, *The fit's numerics*).

Each *_oracle below is the straightforward version (the code before it was made faster),
kept here as the test oracle: ``identify`` must not move a single bit when the numerics
around the plant are reorganised (docs/identification-speed-log.md, *The fit's numerics*)."""

from __future__ import annotations

import numpy as np
import pytest

import admittance.ident.fit as fit
from admittance.formats.dataset import load_dataset
from admittance.ident.equation_error import initial_states
from admittance.ident.fit import (_Covariance, _lm_step, _Problem, autocorrelation_time, autocovariances, chord_slopes,
                                  closest_starts, fit_output_error, normal_equations)
from admittance.ident.model import INDEX, Simulator, free_params, vector_from
from admittance.ident.synthetic import MX64, SynthSpec, generate


def _bits_equal(x, y) -> bool:
    x, y = np.asarray(x), np.asarray(y)
    return x.shape == y.shape and np.array_equal(x, y, equal_nan=True) and bool((np.signbit(x) == np.signbit(y)).all())


def normal_equations_oracle(jac, residuals, n_g, fit_x0):
    n_t = len(jac)
    n = n_g + (2 * n_t if fit_x0 else 0)
    a = np.zeros((n, n))
    b = np.zeros(n)
    for k, (jk, rk) in enumerate(zip(jac, residuals)):
        gk = jk[:n_g]
        a[:n_g, :n_g] += gk @ gk.T
        b[:n_g] += gk @ rk
        if fit_x0:
            xk = jk[n_g:]
            s = slice(n_g + 2 * k, n_g + 2 * k + 2)
            cross = gk @ xk.T
            a[:n_g, s] = cross
            a[s, :n_g] = cross.T
            a[s, s] = xk @ xk.T
            b[s] = xk @ rk
    return a, b


def autocovariances_oracle(residuals, max_lag):
    out = []
    for r in residuals:
        if r.size < 2:
            continue
        x = r - r.mean()
        n = x.size
        lags = min(max_lag, n - 1)
        spec = np.fft.rfft(x, 2 * n)
        out.append(np.fft.irfft(spec * np.conj(spec))[: lags + 1])
    return out


def _blocks(rng, n_g, lengths, rows_extra=2):
    # Columns of very different scales, and one exactly zero row with a negative step's sign
    # (a parameter the data do not see): the signs of zeros must come out as they did.
    jac = []
    for n_k in lengths:
        jk = rng.standard_normal((n_g + rows_extra, n_k)) * 10.0 ** rng.integers(-6, 4, (n_g + rows_extra, 1))
        if n_g:
            jk[0] = -0.0
        jac.append(jk)
    return jac, [rng.standard_normal(n_k) * 1e-3 for n_k in lengths]


@pytest.mark.parametrize("n_g", [0, 1, 2, 3, 4, 5, 7])
@pytest.mark.parametrize("fit_x0", [True, False])
def test_normal_equations_are_bit_for_bit_the_per_trial_sums(n_g, fit_x0):
    rng = np.random.default_rng(n_g)
    lengths = [1201, 1201, 60, 1141, 2, 1201, 777]
    jac, residuals = _blocks(rng, n_g, lengths, 2 if fit_x0 else 0)
    a, b = normal_equations(jac, residuals, n_g, fit_x0)
    a0, b0 = normal_equations_oracle(jac, residuals, n_g, fit_x0)
    assert _bits_equal(a, a0) and _bits_equal(b, b0)
    # And they are the normal equations of the dense problem (the oracle is not wrong itself).
    n = a.shape[0]
    dense = np.zeros((sum(lengths), n))
    row = 0
    for k, jk in enumerate(jac):
        dense[row : row + jk.shape[1], :n_g] = jk[:n_g].T
        if fit_x0:
            dense[row : row + jk.shape[1], n_g + 2 * k : n_g + 2 * k + 2] = jk[n_g:].T
        row += jk.shape[1]
    np.testing.assert_allclose(a, dense.T @ dense, rtol=1e-12, atol=1e-12 * np.abs(a).max(initial=0.0))
    np.testing.assert_allclose(b, dense.T @ np.concatenate(residuals), rtol=1e-12, atol=1e-12 * np.abs(b).max(initial=0.0))


def test_chord_slopes_are_the_plain_quotient_in_the_simulations_own_array():
    rng = np.random.default_rng(2)
    perturbed = rng.standard_normal((6, 1201))
    base = rng.standard_normal(1201)
    steps = np.array([1e-2, -3e-4, 7e-6, 1e-3, 1e-3, 1e-2])
    expected = (perturbed - base[None, :]) / steps[:, None]
    kept = perturbed.copy()
    frozen = perturbed.copy()
    frozen.flags.writeable = False
    out = chord_slopes(perturbed, base, steps)
    assert _bits_equal(out, expected) and np.shares_memory(out, perturbed)
    # A read-only array (a caller's cache) is left alone and gives the same numbers.
    out_frozen = chord_slopes(frozen, base, steps)
    assert _bits_equal(out_frozen, expected) and _bits_equal(frozen, kept)


def test_autocovariances_match_a_direct_sum_and_keep_the_pieces_order():
    rng = np.random.default_rng(3)
    pieces = [rng.standard_normal(n) for n in (50, 1, 37, 50, 0, 64, 37)]
    out = autocovariances(pieces, max_lag=10)
    kept = [p for p in pieces if p.size >= 2]
    assert len(out) == len(kept)
    for acov, p in zip(out, kept):
        x = p - p.mean()
        direct = np.array([x[: x.size - k] @ x[k:] for k in range(min(10, x.size - 1) + 1)])
        np.testing.assert_allclose(acov, direct, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("lengths", [[1201] * 20, [60, 61, 57, 60, 61, 59, 60] * 3, [1141, 1140, 1144, 1201, 1141],
                                     [1000, 1024, 997, 2, 3], list(range(2, 40))])
def test_autocovariances_are_bit_for_bit_the_per_piece_transform(lengths):
    rng = np.random.default_rng(len(lengths))
    # Smooth residuals (model error) plus noise, as a fit leaves them.
    residuals = [np.convolve(rng.standard_normal(n + 30), np.ones(30) / 30, "valid")[:n] * 1e-3
                 + rng.standard_normal(n) * 1e-4 for n in lengths]
    for max_lag in (400, 2000, 5):
        got, expected = autocovariances(residuals, max_lag), autocovariances_oracle(residuals, max_lag)
        assert len(got) == len(expected) and all(_bits_equal(g, e) for g, e in zip(got, expected))
    assert autocorrelation_time(residuals) > 1.0  # smooth residuals: correlated samples


class _Linear:
    """r(z) = J z − y over one 'trial': the LM's damped solve can be compared with the formula."""

    def __init__(self, jac, y):
        self.jac, self.y = jac, y

    def residuals(self, z):
        return [self.jac @ z - self.y]

    def residuals_of(self, zs):
        return [self.residuals(z) for z in zs]


def test_the_damped_system_is_a_plus_lambda_diag_bit_for_bit():
    rng = np.random.default_rng(2)  # a draw where LAPACK's step does follow the zero's sign
    jac, y = rng.normal(size=(80, 5)) * np.array([1e-3, 1.0, 10.0, 1e2, 1e-1]), rng.normal(size=80)
    problem = _Linear(jac, y)
    z = np.zeros(5)
    r = problem.residuals(z)
    a, b = normal_equations([jac.T], r, 5, False)
    # Signed zeros: a + lam·diag(d) turned a −0 off the diagonal into +0, and with a zero in b
    # the sign of that component of the step (and of z + step at −0) follows it.
    a[0, 1:] = a[1:, 0] = -0.0
    b[0] = 0.0
    z[0] = -0.0
    cost = float(r[0] @ r[0])
    lam = 0.37
    lo, hi = np.full(5, -np.inf), np.full(5, np.inf)
    z_new, *_ = _lm_step(problem, z, a, b, cost, lam, lo, hi)
    d = np.maximum(np.diag(a), 1e-12 * max(np.diag(a).max(), 1e-300))
    expected = z + np.linalg.solve(a + lam * np.diag(d), -b)
    assert z_new is not None and _bits_equal(z_new, expected)


class _Batch:
    """A stand-in Simulator: fixed simulated rows per trial, whatever the vector."""

    def __init__(self, sims, measured):
        self._sims, self.measured = sims, measured

    def run(self, rows, x0):
        assert rows.shape[0] == x0.shape[0]
        return [s.copy() for s in self._sims]


def test_the_start_screen_picks_by_each_rows_mean_square_as_before():
    rng = np.random.default_rng(5)
    measured = [rng.standard_normal(int(n)) for n in rng.integers(9, 3000, 60)]
    # Per trial, start 2 simulates a shuffle of start 1: the same squares summed in another
    # order, so which of the two is picked is decided by the summation's last bits.
    sims = []
    for m in measured:
        rows = m[None, :] + rng.standard_normal((4, m.size)) * np.array([[3e-3], [1e-3], [1e-3], [2e-3]])
        rows[2] = m + rng.permutation(rows[1] - m)
        sims.append(rows)
    starts = [rng.standard_normal((len(measured), 2)) for _ in range(4)]
    x0, residuals = closest_starts(_Batch(sims, measured), np.zeros(3), starts)
    picks = []
    for k, (s, m) in enumerate(zip(sims, measured)):
        pick = int(np.argmin([np.mean((s[i] - m) ** 2) for i in range(len(starts))]))
        picks.append(pick)
        assert _bits_equal(x0[k], starts[pick][k]) and _bits_equal(residuals[k], s[pick] - m)
    assert {1, 2} <= set(picks)  # the last bits decided both ways: the test can tell orders apart


@pytest.fixture(scope="module")
def small_fit(tmp_path_factory):
    folder = generate(tmp_path_factory.mktemp("numerics"), SynthSpec(n_trials=4, duration=3.0, seed=2))
    ds = load_dataset(folder)
    sim = Simulator(ds.trials, ds.mode)
    start = vector_from(MX64)
    start[:3] *= 1.2
    result = fit_output_error(sim, start, free_params("geometry", [], False), initial_states(ds.trials),
                              torque_scale=0.3, max_iter=8)
    return sim, result


def test_the_covariance_reuses_the_last_iterations_normal_matrix_bit_for_bit(small_fit):
    _, result = small_fit
    fresh = _Covariance(result.jacobian, result.residuals, len(result.free), True)
    assert result.iterations > 1  # so that a stale JᵀJ (an earlier iteration's) would show
    assert _bits_equal(result.uncertainty.full(), fresh.full())
    assert all(result.sigma[n] > 0 for n in result.free)


def test_residuals_and_jacobian_blocks_are_the_plain_formulas_on_the_plants_output(small_fit):
    sim, result = small_fit
    problem = _Problem(sim, result.vector, result.free, True, 0.3)
    z = np.concatenate([[result.value(n) for n in result.free], result.x0.ravel()])
    residuals = problem.residuals(z)
    simulated = sim.run(result.vector[None, :], result.x0[None, :, :])
    assert all(_bits_equal(r, s[0] - m) for r, s, m in zip(residuals, simulated, sim.measured))
    assert all(_bits_equal(r, rr) for r, rr in zip(residuals, result.residuals))
    upper = np.full(z.size, np.inf)
    jac = problem.jacobian(z, residuals, upper)
    g, x0 = problem.split(z)
    h = problem.steps(g, upper)
    n_g = len(g)
    rows = np.repeat(result.vector[None, :], n_g + 2, axis=0)
    for j, name in enumerate(result.free):
        rows[j, INDEX[name]] += h[j]
    x0s = np.repeat(x0[None, :, :], n_g + 2, axis=0)
    x0s[n_g, :, 0] += fit.THETA0_STEP
    x0s[n_g + 1, :, 1] += fit.OMEGA0_STEP
    steps = np.concatenate([h, [fit.THETA0_STEP, fit.OMEGA0_STEP]])
    for jk, s, r, m in zip(jac, sim.run(rows, x0s), residuals, sim.measured):
        assert _bits_equal(jk, (s - (r + m)[None, :]) / steps[:, None])
