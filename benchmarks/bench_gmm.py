"""EM fit of a 3-component error mixture: scikit-learn's GaussianMixture vs prismap, side by side.

Scene: ``--samples`` disparity errors (default 3 million) drawn with seed 0 from a stereo-like mixture
(a narrow core, a medium shoulder and a 5 % wide outlier component). scikit-learn fits the raw samples
(its defaults: k-means initialisation, tol 1e-3, max_iter 100, one init); prismap bins them at 1/32 px
and fits the histogram (4 starts, relative tol 1e-9). Both fitted mixtures are then scored the same way:
the mean log-density of the raw samples under :meth:`prismap.gmm.GaussianMixture.logpdf`.

Run: ``.venv/bin/python benchmarks/bench_gmm.py [--samples N]``. Goal: prismap >= 50x faster, mean
log-likelihood no worse than 0.1 % of scikit-learn's.
"""

import argparse
import time

import numpy as np
from sklearn.mixture import GaussianMixture as SklearnMixture

from prismap.gmm import GaussianMixture, fit_mixture

TRUTH = GaussianMixture([0.70, 0.25, 0.05], [0.05, -0.20, -3.0], [0.30, 1.00, 12.0])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=3_000_000)
    args = parser.parse_args()

    errors = TRUTH.sample(args.samples, np.random.default_rng(0))
    print(
        f"scene: {args.samples} errors from weights {TRUTH.weights.tolist()}, means {TRUTH.means.tolist()} px, "
        f"sigmas {TRUTH.sigmas.tolist()} px (seed 0)"
    )

    fit_mixture(errors[:10_000], n_components=3, bin_width=1 / 32)  # compile the numba kernels first
    start = time.perf_counter()
    ours = fit_mixture(errors, n_components=3, bin_width=1 / 32).mixture
    ours_s = time.perf_counter() - start

    start = time.perf_counter()
    sk = SklearnMixture(n_components=3, random_state=0).fit(errors[:, None])
    sk_s = time.perf_counter() - start
    theirs = GaussianMixture(sk.weights_, sk.means_.ravel(), np.sqrt(sk.covariances_.ravel()))

    ours_ll = ours.logpdf(errors).mean()
    theirs_ll = theirs.logpdf(errors).mean()
    for label, mixture, seconds, ll in (("prismap", ours, ours_s, ours_ll), ("sklearn", theirs, sk_s, theirs_ll)):
        order = np.argsort(-mixture.weights)
        print(
            f"{label:8s} {seconds:8.3f} s  mean ln p = {ll:.6f}  w = {np.round(mixture.weights[order], 3).tolist()}"
            f"  mu = {np.round(mixture.means[order], 3).tolist()}  sigma = {np.round(mixture.sigmas[order], 3).tolist()}"
        )
    print(f"sklearn converged: {sk.converged_} after {sk.n_iter_} iterations")
    print(f"speed ratio sklearn / prismap: {sk_s / ours_s:.1f}x")
    print(
        f"log-likelihood difference (prismap - sklearn): {ours_ll - theirs_ll:+.6f} nats/sample "
        f"({100 * (ours_ll - theirs_ll) / abs(theirs_ll):+.4f} % of sklearn's)"
    )


if __name__ == "__main__":
    main()
