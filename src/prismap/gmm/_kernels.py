"""numba kernels of the EM fit of a 1-D Gaussian mixture to weighted points (bin centres or samples).

The wrappers in ``_em.py`` check and convert every argument; these kernels assume contiguous float64
arrays, positive weights and a positive variance floor.
"""

import math

import numba
import numpy as np

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


@numba.njit(cache=True)
def em_weighted(
    points,
    counts,
    weights,
    means,
    variances,
    var_floor,
    tol,
    max_iter,
    floor_density=0.0,
    floor_weight=0.0,
    prior_count=0.0,
):
    """Run EM on weighted 1-D points from the given start; return the fit and its log-likelihood.

    With ``floor_density > 0`` the mixture has one more component of constant density (a matcher's failures,
    uniform over its search range): ``p(x) = (1 - w_f) sum_j w_j N(x; mu_j, var_j) + w_f floor_density``.
    Its weight is the MAP estimate under a Dirichlet prior that adds ``prior_count`` pseudo-points to it
    (``w_f = (R_f + prior_count) / (N + prior_count)``, ``R_f`` its responsibilities); the stopping rule
    watches the log-posterior ``lnL + prior_count ln w_f``, which MAP-EM never lowers.

    Parameters
    ----------
    points : (N,) float64, pixels
        Bin centres or samples.
    counts : (N,) float64, > 0
        Their weights (histogram counts).
    weights, means, variances : (G,) float64
        Starting mixture (pixels, pixels^2); not modified.
    var_floor : float, pixels^2, > 0
    tol : float
        Stop when the log-likelihood rises by less than ``tol * |lnL|``.
    max_iter : int

    Returns
    -------
    weights, means, variances : (G,) float64
    log_likelihood : float
        ``sum counts * log p(points)`` of the returned parameters.
    n_iter : int
        M-steps taken.
    converged : bool
    """
    n_points = points.size
    n_comp = weights.size
    use_floor = floor_density > 0.0
    w_f = floor_weight if use_floor else 0.0
    w = weights * (1.0 - w_f)  # every weight of the (G + 1)-component mixture, summing to 1
    mu = means.copy()
    var = variances.copy()
    total = 0.0
    for i in range(n_points):
        total += counts[i]
    log_floor = math.log(floor_density) if use_floor else 0.0
    log_terms = np.empty(n_comp)
    coef = np.empty(n_comp)
    resp_sum = np.empty(n_comp)
    first = np.empty(n_comp)
    second = np.empty(n_comp)
    previous = -np.inf
    log_lik = -np.inf
    n_iter = 0
    converged = False
    while True:
        # E-step: log-likelihood of the current parameters and the sufficient statistics of the
        # responsibilities. Deviations are taken from the current means so the variance update
        # does not subtract two large numbers.
        for j in range(n_comp):
            coef[j] = math.log(w[j]) - 0.5 * math.log(var[j]) - _LOG_SQRT_2PI if w[j] > 0.0 else -np.inf
            resp_sum[j] = 0.0
            first[j] = 0.0
            second[j] = 0.0
        log_lik = 0.0
        floor_sum = 0.0
        floor_term = math.log(w_f) + log_floor if use_floor and w_f > 0.0 else -np.inf
        for i in range(n_points):
            x = points[i]
            peak = floor_term
            for j in range(n_comp):
                if w[j] > 0.0:
                    dev = x - mu[j]
                    log_terms[j] = coef[j] - 0.5 * dev * dev / var[j]
                else:
                    log_terms[j] = -np.inf
                if log_terms[j] > peak:
                    peak = log_terms[j]
            floor_share = math.exp(floor_term - peak)
            acc = floor_share
            for j in range(n_comp):
                log_terms[j] = math.exp(log_terms[j] - peak)
                acc += log_terms[j]
            log_lik += counts[i] * (peak + math.log(acc))
            scale = counts[i] / acc
            floor_sum += floor_share * scale
            for j in range(n_comp):
                r = log_terms[j] * scale
                dev = x - mu[j]
                resp_sum[j] += r
                first[j] += r * dev
                second[j] += r * dev * dev
        objective = log_lik + (prior_count * math.log(w_f) if use_floor and prior_count > 0.0 else 0.0)
        if abs(objective - previous) <= tol * abs(objective):
            converged = True
            break
        if n_iter >= max_iter:
            break
        previous = objective
        # M-step. A component that lost all its points keeps weight 0 and drops out.
        norm = total + (prior_count if use_floor else 0.0)
        if use_floor:
            w_f = (floor_sum + prior_count) / norm
        for j in range(n_comp):
            if resp_sum[j] <= 0.0:
                w[j] = 0.0
                continue
            shift = first[j] / resp_sum[j]
            w[j] = resp_sum[j] / norm
            mu[j] += shift
            var[j] = max(second[j] / resp_sum[j] - shift * shift, var_floor)
        n_iter += 1
    if use_floor:
        gaussian = 0.0
        for j in range(n_comp):
            gaussian += w[j]
        for j in range(n_comp):
            w[j] = w[j] / gaussian if gaussian > 0.0 else 1.0 / n_comp
    return w, mu, var, w_f, log_lik, n_iter, converged


@numba.njit(cache=True)
def kmeans_plus_plus(points, counts, n_centres, uniforms):
    """k-means++ seeding on weighted points: each new centre is drawn with probability ∝ count * D².

    ``uniforms`` holds ``n_centres`` numbers in [0, 1) from the caller's seeded generator.
    Returns the (n_centres,) float64 centres (pixels).
    """
    n_points = points.size
    centres = np.empty(n_centres)
    dist2 = np.empty(n_points)
    cumulative = np.empty(n_points)
    running = 0.0
    for i in range(n_points):
        running += counts[i]
        cumulative[i] = running
    pick = np.searchsorted(cumulative, uniforms[0] * running, side="right")
    centres[0] = points[min(pick, n_points - 1)]
    for i in range(n_points):
        d = points[i] - centres[0]
        dist2[i] = d * d
    for k in range(1, n_centres):
        running = 0.0
        for i in range(n_points):
            running += counts[i] * dist2[i]
            cumulative[i] = running
        if running <= 0.0:
            centres[k] = centres[k - 1]
            continue
        pick = min(np.searchsorted(cumulative, uniforms[k] * running, side="right"), n_points - 1)
        centres[k] = points[pick]
        for i in range(n_points):
            d = points[i] - centres[k]
            if d * d < dist2[i]:
                dist2[i] = d * d
    return centres
