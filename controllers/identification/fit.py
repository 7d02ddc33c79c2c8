"""Fit of the joint model [2-36..2-45] to an experiment's time data, as the lab's thesis did it
(rig-facts §1 "Experiments": differential evolution, population 40, up to 1500 generations),
then a local polish and the model's quality by [2-49]:

    Fit = (1 - ||y - y_hat|| / ||y - mean(y)||) * 100 %

The search runs over the logarithm of each positive parameter relative to a prior model (the
set the rig file names), within a factor ``SPAN`` of it: so a bound reads "a third to three
times the prior". The dead time is searched on [0, MAX_DEAD_TIME_S], Coulomb friction as a
fraction of the static, and the start's held friction torque ``c`` within +-2 prior Fs. Held at
the prior's values (docs/identification.md shows why): the gain K_mdl (from V_MV to the angle,
scaling every torque of the model together changes nothing, so only the torques relative to
it are identifiable); the inertia J (its pole, D / J, is at 50-230 Hz, far beyond what the
regulator's 3.6 Hz lag lets through, and it trades off against T_ep and T_dly); the Stribeck
velocity vs (0.1 deg/s, below what the angle's noise lets a 1 ms difference resolve) and the
shape parameters alpha and beta, which trade off against Fs.

Confidence: the polish (``scipy.optimize.least_squares``) gives the Jacobian at the optimum;
the parameters' covariance is s^2 (J^T J)^-1 in the search coordinates, so a log parameter's
standard deviation reads as a relative one. That formula assumes independent residuals; the
residuals of a fit to a pneumatic joint are mostly model error, correlated over many samples,
so the covariance is scaled by the residuals' integrated autocorrelation (1 + 2 sum rho_k over
the initial positive sequence of pairs of lags, Geyer 1992): the number of independent samples
the data really holds. That is the noise's and the model error's share at one optimum; the
final population's spread says how far apart the fits are that the data rates as good as it.
The polish starts from the population's best (the fit) and from points along the ridge of the
regulator's lag against the dead time (:func:`ridge_polishes`), where friction leaves a row of
shallow basins: how far from the fit lie those that fit as well as the best of them is the
ridge's share (:func:`ridge_spread`). The uncertainty the fit states (``stated_std``) is
those, and the model's own error (:func:`model_error_std`), in quadrature (issue 32: the
Jacobian's figure alone was about a quarter of the errors made on perturbed simulated plants;
bench.identification reports the coverage).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import differential_evolution, least_squares, minimize_scalar

from controllers.identification.simulate import FITTED, samples_per_step, simulate, simulate_experiments
from hal.identified import JointParams

SPAN = {"D": 3.0, "K": 3.0, "T_ep": 3.0, "Fs": 2.5}  # factor either side of the prior
MAX_DEAD_TIME_S = 0.3
DIFF_STEP = 1e-3  # the polish's forward-difference step, relative to |x| in search coordinates
SEARCH = ("D", "K", "T_ep", "T_dly", "Fs", "Fc_ratio", "c")  # c: one per estimation experiment
C_SPAN = 2.0  # each experiment's held friction torque c is looked for within +-C_SPAN prior Fs [N m]
RIDGE_STARTS = 7  # polishes started along the lag/dead-time ridge (:func:`ridge_polishes`): T_ep every 1.44x


@dataclass
class Experiment:
    """One joint's experiment as the fit needs it: the recording's period ``dt`` [s], the
    pressure lever L (A_H dP_set,H - A_L dP_set,L) [N m per unit K_mdl] per sample, the joint
    angle's deviation from the start ``y`` [deg] per sample (the angle before that sample's
    command), and what describes it (signal, operating point, rig hash, source file)."""

    dt: float
    lever: np.ndarray
    y: np.ndarray
    t: np.ndarray
    u: np.ndarray  # V_MV commanded [V]
    start_deg: float
    info: dict = field(default_factory=dict)
    r: np.ndarray | None = None  # the joint's reference, deviation from the start [deg] (closed loop)


@dataclass
class FitResult:
    params: JointParams  # the identified set (geometry and shape parameters from the prior)
    c: list[float]  # held friction torque at the start of each estimation experiment [N m]
    fit_percent: list[float]  # [2-49] on each estimation experiment
    heldout_fit_percent: list[float]  # [2-49] on each validation experiment
    relative_std: dict[str, float]  # 1 sigma per fitted parameter: relative (T_dly [s], Fc_ratio: absolute); nan: not determined
    population_std: dict[str, float]  # the final DE population's spread, in the same terms (:func:`_population_std`)
    ridge_std: dict[str, float]  # how far the lag/dead-time ridge's optima as good as the best lie (:func:`ridge_spread`)
    stated_std: dict[str, float]  # what the fit states: the two in quadrature, in the same terms
    correlation: float  # the residuals' integrated autocorrelation: samples per independent one (>= 1)
    wall_s: float
    generations: int
    evaluations: int
    settings: dict

    def summary(self) -> dict:
        return {"params": {n: getattr(self.params, n) for n in FITTED}, "c_nm": list(self.c),
                "fit_percent": self.fit_percent, "heldout_fit_percent": self.heldout_fit_percent,
                "relative_std": self.relative_std, "population_std": self.population_std, "ridge_std": self.ridge_std,
                "stated_std": self.stated_std, "residual_correlation": self.correlation,
                "wall_s": self.wall_s, "generations": self.generations,
                "evaluations": self.evaluations, "settings": self.settings}


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> float:
    """[2-49]: (1 - ||y - y_hat|| / ||y - mean(y)||) * 100 [%]."""
    spread = np.linalg.norm(y - np.mean(y))
    return float((1.0 - np.linalg.norm(y - y_hat) / spread) * 100.0) if spread > 0 else float("nan")


class _Problem:
    """The search coordinates <-> parameter rows, and the residuals on the estimation data:
    one or more experiments, each with its own held friction torque c at its start."""

    def __init__(self, prior: JointParams, data: list[Experiment], step: float):
        self.prior, self.data, self.step = prior, data, step
        self.m = [samples_per_step(step, d.dt) for d in data]
        self.targets = [d.y[m::m] for d, m in zip(data, self.m)]
        self.scale = max(float(np.std(np.concatenate(self.targets))), 1e-6)
        self.size = sum(len(t) for t in self.targets)
        lo, hi = [], []
        for name in SEARCH[:-1]:
            if name in SPAN:
                lo.append(-math.log(SPAN[name]))
                hi.append(math.log(SPAN[name]))
            elif name == "T_dly":
                lo.append(0.0)
                hi.append(MAX_DEAD_TIME_S)
            else:  # Fc_ratio
                lo.append(0.0)
                hi.append(1.0)
        lo += [-C_SPAN * prior.Fs] * len(data)
        hi += [C_SPAN * prior.Fs] * len(data)
        self.bounds = np.array([lo, hi]).T

    def rows(self, x: np.ndarray, experiment: int = 0) -> np.ndarray:
        """Search points (S, N) -> parameter rows (S, FITTED + c) for one experiment."""
        x = np.atleast_2d(x)
        p = self.prior
        out = np.empty((len(x), len(FITTED) + 1))
        out[:, 0], out[:, 1] = p.K_mdl, p.J
        for col, name in enumerate(("D", "K", "T_ep"), start=2):
            out[:, col] = getattr(p, name) * np.exp(x[:, col - 2])
        out[:, 5] = x[:, 3]
        out[:, 6] = p.Fs * np.exp(x[:, 4])
        out[:, 7] = x[:, 5] * out[:, 6]
        out[:, 8] = p.vs
        out[:, 9] = x[:, 6 + experiment]
        return out

    def errors(self, x: np.ndarray) -> np.ndarray:
        """Scaled output errors, all experiments end to end: (S, samples)."""
        angles = simulate_experiments([self.rows(x, i) for i in range(len(self.data))], [d.lever for d in self.data],
                                      [d.dt for d in self.data], self.step, self.prior.alpha, self.prior.beta)
        parts = [y_hat[:, :len(target)] - target for y_hat, target in zip(angles, self.targets)]
        return np.concatenate(parts, axis=1) / self.scale

    def cost(self, xt: np.ndarray) -> np.ndarray:
        """Mean square scaled error per member; DE's vectorised call passes (N, S)."""
        err = self.errors(xt.T)
        return np.mean(err * err, axis=1)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.errors(x)[0]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """d residuals / d x by forward differences, every column's point simulated in one
        vectorised call: the cost of one evaluation of the population rather than one per
        parameter. The steps are scipy's for ``least_squares(diff_step=DIFF_STEP)``: relative
        to |x| (sqrt(eps) max(1, |x|) where that is lost to rounding), turned inward at a bound."""
        sign = np.where(x >= 0, 1.0, -1.0)
        h = DIFF_STEP * sign * np.abs(x)
        h = np.where((x + h) - x == 0.0, np.sqrt(np.finfo(float).eps) * sign * np.maximum(1.0, np.abs(x)), h)
        outside = (x + h < self.bounds[:, 0]) | (x + h > self.bounds[:, 1])
        h = np.where(outside, -h, h)
        err = self.errors(np.vstack([x, x + np.diag(h)]))
        return ((err[1:] - err[0]) / h[:, None]).T

    def params(self, x: np.ndarray) -> tuple[JointParams, list[float]]:
        row = self.rows(x)[0]
        return (self.prior.replace(dict(zip(FITTED, map(float, row[:9])))),
                [float(v) for v in np.atleast_2d(x)[0, 6:]])


def fit_joint(estimation: list[Experiment], prior: JointParams, validation: list[Experiment] = (),
              population: int = 40, generations: int = 1500, step: float = 0.005, tol: float = 1e-3,
              seed: int = 0, progress=None) -> FitResult:
    """Differential evolution (``population`` members in all, at most ``generations``; it stops
    earlier when the population's spread in cost falls below ``tol`` of its mean), then
    a least-squares polish of its best (the fit) and polishes along the lag/dead-time ridge
    (what the fit might as well have been: the ridge's share of the stated uncertainty);
    ``progress(generation, best_cost)`` after each generation. The Fit % is reported on the
    estimation data and on each ``validation`` experiment (held out)."""
    started = time.perf_counter()
    problem = _Problem(prior, list(estimation), step)
    dims = len(problem.bounds)
    state = {"generation": 0}

    def callback(intermediate_result):
        state["generation"] += 1
        if progress is not None:
            progress(state["generation"], float(intermediate_result.fun))

    found = differential_evolution(problem.cost, problem.bounds, popsize=max(population // dims, 1), maxiter=generations,
                                   tol=tol, seed=seed, polish=False, vectorized=True, updating="deferred",
                                   init="sobol", callback=callback)
    optima = ridge_polishes(problem, found.x)
    polished = optima[0]  # the population's best, polished: the fit
    best = polished.x if 2 * polished.cost / problem.size <= found.fun else found.x
    params, c = problem.params(best)
    estimation_fit = [fit_percent(t, t + problem.scale * e) for t, e in
                      zip(problem.targets, np.split(problem.residuals(best), np.cumsum([len(t) for t in problem.targets])[:-1]))]
    heldout = [heldout_fit(params, v, step, C_SPAN * prior.Fs) for v in validation]
    correlation = integrated_autocorrelation(polished.fun, [len(t) for t in problem.targets])
    jacobian_std, spread = _relative_std(polished, problem.bounds, correlation), _population_std(found)
    modelled = model_error_std(problem, best, polished.jac)
    ridge = ridge_spread(optima, best, problem.size / correlation)
    stated = {n: math.hypot(jacobian_std[n], spread[n], modelled[n], ridge[n]) if jacobian_std[n] == jacobian_std[n]
              else float("nan") for n in jacobian_std}
    return FitResult(params, c, estimation_fit, heldout, jacobian_std, spread, ridge, stated, correlation,
                     time.perf_counter() - started, state["generation"],
                     int(found.nfev + sum(o.nfev for o in optima)),
                     {"population": population, "generations": generations, "step_s": step, "tol": tol,
                      "seed": seed, "search": list(SEARCH[:-1]), "experiments": len(problem.data)})


def ridge_polishes(problem: "_Problem", x: np.ndarray) -> list:
    """Least-squares polishes from ``x`` (differential evolution's best; the first) and from
    RIDGE_STARTS points along the ridge of the regulator's lag T_ep against the dead time T_dly:
    T_ep across its search range, T_dly moved to keep their sum (the lag a slow path sees) and
    the rest as in ``x``. Along that ridge static friction makes the cost rugged, a row of
    shallow basins the population can settle in together (a swing's recording: T_ep at 0.4 of
    the truth, D 0.6 % off, where a basin near the truth fitted better), and the damping and
    the spring trade against where on it the fit sits; with the model's own error the lowest
    basin need not be the truth's either (the middle joint's experiments: T_dly 21 % off there,
    5 % at the population's), so they measure the fit's uncertainty, not replace it."""
    bounds = (problem.bounds[:, 0], problem.bounds[:, 1])
    lag = problem.prior.T_ep * math.exp(x[2]) + x[3]
    starts = [np.asarray(x, dtype=float)]
    for u in np.linspace(problem.bounds[2, 0], problem.bounds[2, 1], RIDGE_STARTS):
        start = starts[0].copy()
        start[2] = u
        start[3] = min(max(lag - problem.prior.T_ep * math.exp(u), bounds[0][3]), bounds[1][3])
        starts.append(start)
    optima = [least_squares(problem.residuals, s, jac=problem.jacobian, bounds=bounds, x_scale="jac") for s in starts]
    return optima


def ridge_spread(optima: list, fit: np.ndarray, independent: float) -> dict[str, float]:
    """How far (the largest distance, in search coordinates) from the ``fit`` lie the optima of
    :func:`ridge_polishes` that the data cannot tell from the lowest of them: a sum of squares
    within 1 + 1/``independent`` of its, i.e. a chi-square within 1 on the residuals'
    independent samples (:func:`integrated_autocorrelation`), the profile likelihood's 1 sigma.
    0 when the fit is the only one; the Jacobian's figure sees only the basin the fit sits in."""
    lowest = min(o.cost for o in optima)
    alike = [o.x for o in optima if o.cost <= lowest * (1.0 + 1.0 / max(independent, 1.0))]
    far = np.max(np.abs(np.array(alike) - fit), axis=0)
    return {name: float(far[i]) for i, name in enumerate(SEARCH[:-1])}


def predict(params: JointParams, data: Experiment, step: float, c: float) -> np.ndarray:
    """The model's angle deviation [deg] on the step grid (sample m, 2m, ...) for ``data``."""
    row = np.array([[params.K_mdl, params.J, params.D, params.K, params.T_ep, params.T_dly, params.Fs, params.Fc,
                     params.vs, c]])
    return simulate(row, data.lever, data.dt, step, params.alpha, params.beta)[0]


def best_c(params: JointParams, data: Experiment, step: float, bound: float) -> float:
    """The start's held friction torque c [N m] within +-``bound`` that fits ``data`` best: an
    initial condition of that experiment, not a model parameter (the fit's own range for it,
    +-C_SPAN prior Fs: bounded by the fitted Fs instead, a fit that trades static friction
    against c is judged on a start it could not have chosen)."""
    m = samples_per_step(step, data.dt)
    target = data.y[m::m]

    def cost(c):
        y_hat = predict(params, data, step, c)[:len(target)]
        return float(np.mean((y_hat - target[:len(y_hat)]) ** 2))

    return float(minimize_scalar(cost, bounds=(-bound, bound), method="bounded", options={"xatol": 1e-4}).x)


def heldout_fit(params: JointParams, data: Experiment, step: float, c_bound: float) -> float:
    """[2-49] on data the fit did not see (only its start's c is chosen, :func:`best_c`)."""
    m = samples_per_step(step, data.dt)
    target = data.y[m::m]
    y_hat = predict(params, data, step, best_c(params, data, step, c_bound))[:len(target)]
    return fit_percent(target[:len(y_hat)], y_hat)


def _population_std(found) -> dict[str, float]:
    """The spread (standard deviation) of each parameter over differential evolution's final
    population, relative for log parameters: fits the data can barely tell apart (the lag
    T_ep against the dead time T_dly, along which the friction makes the cost rugged, so the
    Jacobian's figure alone is too small), and large when the search stopped unconverged."""
    spread = np.std(found.population, axis=0)
    return {name: float(spread[i]) for i, name in enumerate(SEARCH[:-1])}


def integrated_autocorrelation(residuals: np.ndarray, lengths: list[int]) -> float:
    """1 + 2 sum_k rho_k of the residuals, per experiment (``lengths``: their samples, end to
    end), by Geyer's initial positive sequence (1992): the sums of adjacent pairs of lags,
    rho_2m + rho_2m+1, up to the first that is not positive (beyond that it is noise), weighted
    by length; at least 1. White residuals give 1; residuals correlated over m samples, about
    m. Pairs, not single lags: a residual of white sensor noise over a slow model error has
    single lags near 0 that turn negative by chance at lag 1, and stopping there read 1 where
    the slow part made it 1.8 (a swing's recording)."""
    total, weight = 0.0, 0
    for part in np.split(np.asarray(residuals, dtype=float), np.cumsum(lengths)[:-1]):
        n = len(part)
        x = part - np.mean(part)
        var = float(np.dot(x, x))
        if n < 4 or var <= 0.0:
            continue
        size = 1 << (2 * n - 1).bit_length()  # autocorrelation by FFT, zero-padded against wrap-around
        spectrum = np.fft.rfft(x, size)
        rho = np.fft.irfft(spectrum * np.conj(spectrum), size)[:n // 2] / var
        pairs = rho[0:len(rho) - 1:2] + rho[1::2]
        ended = np.nonzero(pairs <= 0.0)[0]
        end = ended[0] if len(ended) else len(pairs)
        total += n * (2.0 * float(np.sum(pairs[:end])) - 1.0)
        weight += n
    return max(total / weight, 1.0) if weight else 1.0


CONSIDERED = {"J": 1.5, "vs": 1.5, "beta": 1.5, "alpha": 1.2}  # held parameters' plausible factor (1 sigma)


def model_error_std(problem: "_Problem", x: np.ndarray, jac: np.ndarray) -> dict[str, float]:
    """What the model's own approximations may cost each fitted parameter, in the fit's
    search coordinates: how far one Gauss-Newton step would move the optimum ``x`` if (a) the
    mechanics were stepped at the recording's period instead of ``problem.step`` (the
    discretisation's bias, as in Richardson's estimate), and (b) each parameter held at the
    prior's value (CONSIDERED) were off by its plausible factor (a consider-covariance, as in
    Schmidt's filter): the shifts in quadrature. Neither shows in the residuals' noise."""
    gain = np.linalg.pinv(jac.T @ jac) @ jac.T
    base = problem.residuals(x)
    fine = _Problem(problem.prior, problem.data, min(d.dt for d in problem.data))
    shifts = [gain @ (_on_grid(fine, problem, x) - base)]
    for name, factor in CONSIDERED.items():
        other = _Problem(problem.prior.replace({name: getattr(problem.prior, name) * factor}), problem.data,
                         problem.step)
        shifts.append(gain @ (other.residuals(x) - base))
    spread = np.sqrt(np.sum(np.square(shifts), axis=0))
    return {name: float(spread[i]) for i, name in enumerate(SEARCH[:-1])}


def _on_grid(fine: "_Problem", coarse: "_Problem", x: np.ndarray) -> np.ndarray:
    """``fine``'s residuals at ``x`` sampled on ``coarse``'s grid (scaled as coarse's)."""
    angles = simulate_experiments([fine.rows(x, i) for i in range(len(fine.data))], [d.lever for d in fine.data],
                                  [d.dt for d in fine.data], fine.step, fine.prior.alpha, fine.prior.beta)
    parts = []
    for y_hat, m_fine, m, target in zip(angles, fine.m, coarse.m, coarse.targets):
        ratio = m // m_fine
        picked = y_hat[0, ratio - 1::ratio][:len(target)]
        parts.append(np.pad(picked, (0, len(target) - len(picked))) - target)
    return np.concatenate(parts) / coarse.scale


def _relative_std(polished, bounds: np.ndarray, correlation: float = 1.0) -> dict[str, float]:
    """1 sigma per parameter from the polish's Jacobian: relative for log parameters, the
    covariance scaled by the residuals' ``correlation`` (:func:`integrated_autocorrelation`). A
    parameter the data does not move (a zero Jacobian column, or one pinned at a bound, where
    the polish's Jacobian is one-sided) is nan: not determined by this experiment."""
    jac = polished.jac
    dof = max(polished.fun.size - jac.shape[1], 1)
    s2 = 2 * polished.cost / dof * correlation
    cov = np.linalg.pinv(jac.T @ jac) * s2
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    out = {}
    for i, name in enumerate(SEARCH[:-1]):
        column = np.linalg.norm(jac[:, i])
        at_bound = min(abs(polished.x[i] - bounds[i, 0]), abs(polished.x[i] - bounds[i, 1])) < 1e-6
        out[name] = float(std[i]) if column > 1e-12 and not at_bound else float("nan")
    return out
