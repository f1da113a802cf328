"""Held-out log-likelihood of a matcher's errors: the error model with the matcher-failure component against
today's (Gaussian tails, the whole image's widest component as every class's outlier floor).

Scene: Middlebury 2014 Motorcycle at quarter resolution (scikit-image's copy), matched once by ``--matcher``
(search range 0..``num_disparities`` px). The conditioned model is characterised on the pixels of the top
half of the image (the bottom half's disparities hidden) and scored on the bottom half: the mean log-density,
nats per error, of each held-out error under its class's mixture (and under the whole-image mixture), for
``failures=True`` (uniform failure component over the search range, MAP weight) and ``failures=False``.
The same is printed with the halves swapped. The street worlds' held-out figures come from
``prismap experiment --world street3d`` (results.md, "held-out log-likelihood of the mapping frames' errors").

Run: ``.venv/bin/python benchmarks/bench_failure_heldout.py [--matcher sgbm|bm]``. Goal: with failures, no
lower held-out log-likelihood than today's conditioned model.
"""

import argparse
import time

import numpy as np

from prismap.characterise import characterise_matcher
from prismap.io import load_middlebury_motorcycle
from prismap.stereo import StereoMatcher, make_matcher


class _Masked(StereoMatcher):
    """``matcher``'s output with the pixels outside ``keep`` hidden (NaN): characterise on part of an image."""

    def __init__(self, matcher, disparity, lr, keep):
        self.name = matcher.name
        self._params = matcher.params()
        self._disparity = np.where(keep, disparity, np.float32(np.nan)).astype(np.float32)
        self._lr = None if lr is None else np.where(keep, lr, np.float32(np.nan)).astype(np.float32)

    def compute(self, left, right):
        return self._disparity

    def compute_with_confidence(self, left, right):
        return self._disparity, self._lr

    def params(self):
        return self._params


def _score(model, frame, disparity, lr, test):
    label = model.classify_frame(frame.left, frame.right, disparity, lr)
    errors = np.asarray(frame.disparity_gt, dtype=np.float64) - disparity
    keep = test & (label >= 0) & np.isfinite(errors)
    mixtures = model.class_mixtures
    conditioned = sum(float(m.logpdf(errors[keep & (label == k)]).sum()) for k, m in enumerate(mixtures))
    return conditioned / keep.sum(), float(model.mixture.logpdf(errors[keep]).mean()), int(keep.sum())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--matcher", default="sgbm", choices=("sgbm", "bm"))
    parser.add_argument("--num-disparities", type=int, default=96)
    args = parser.parse_args()
    frame = load_middlebury_motorcycle()
    matcher = make_matcher(args.matcher, num_disparities=args.num_disparities, left_right_check=True)
    disparity, lr = matcher.compute_with_confidence(frame.left, frame.right)
    rows = np.arange(disparity.shape[0])[:, None] < disparity.shape[0] // 2
    top = np.broadcast_to(rows, disparity.shape)
    print(
        f"scene: {frame.name}, {disparity.shape[1]}x{disparity.shape[0]}, {args.matcher} with search range "
        f"{matcher.search_range_px()} px; fit on one half of the rows, score the other"
    )
    print(
        "| fit on | failures | classes | w_f (whole image) | held-out nats/error (classes) | (whole image) | errors |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, train in (("top", top), ("bottom", ~top)):
        for failures in (False, True):
            start = time.perf_counter()
            result = characterise_matcher(
                [frame], _Masked(matcher, disparity, lr, train), dataset="motorcycle", progress=False, failures=failures
            )
            model = result.model
            conditioned, plain, n = _score(model, frame, disparity, lr, ~train)
            print(
                f"| {name} | {failures} | {model.n_classes} | {model.mixture.failure_weight:.2e} | "
                f"{conditioned:.4f} | {plain:.4f} | {n} |  ({time.perf_counter() - start:.0f} s)",
                flush=True,
            )


if __name__ == "__main__":
    main()
