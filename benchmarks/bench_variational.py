"""The variational matcher against OpenCV's StereoSGBM on Middlebury Motorcycle, side by side.

Scene: ``skimage.data.stereo_motorcycle()`` (500 x 741 RGB, ground truth 7.2-59.9 px, +inf = unknown),
disparity range 0-64 px for both. StereoSGBM: ``cv2.StereoSGBM_create`` with prismap's ``sgbm``
defaults (block 5, P1 = 8 * 3 * 25, P2 = 32 * 3 * 25, uniqueness 10, speckle window 100, range 2).
Variational: ``prismap.stereo.make_matcher("variational", max_disparity=64)`` with its defaults.
Cold = the first call in this process (the variational matcher loads its cached numba kernels, or
compiles them with ``--compile``); warm = best of ``--repeats`` further calls. Errors e = gt - computed
on pixels with ground truth; bad-1px counts |e| > 1 px among the pixels a matcher returns, and SGBM's
invalid pixels are reported as its density (the variational output is dense).

Run: ``.venv/bin/python benchmarks/bench_variational.py [--repeats N] [--compile]``.
Goal: variational warm time at most 3x SGBM's, bad-1px at most 25 %.
"""

import argparse
import os
import tempfile
import time


def _timed(function):
    start = time.perf_counter()
    result = function()
    return result, time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--compile",
        action="store_true",
        help="compile the numba kernels in the cold call (fresh, temporary numba cache)",
    )
    args = parser.parse_args()
    if args.compile:
        os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="bench_variational_numba_")

    import cv2
    import numpy as np
    import skimage.data

    from prismap.stereo import make_matcher

    left, right, truth = skimage.data.stereo_motorcycle()
    known = np.isfinite(truth)
    print(
        f"scene: Middlebury Motorcycle {left.shape[1]}x{left.shape[0]} RGB (skimage.data.stereo_motorcycle), "
        f"ground truth {truth[known].min():.1f}-{truth[known].max():.1f} px on {known.mean():.1%} of pixels, "
        f"range 0-64 px; OpenCV {cv2.__version__}, {os.cpu_count()} CPUs"
    )

    sgbm = cv2.StereoSGBM_create(
        minDisparity=0,
        numDisparities=64,
        blockSize=5,
        P1=8 * 3 * 25,
        P2=32 * 3 * 25,
        disp12MaxDiff=-1,
        preFilterCap=63,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
    )
    variational = make_matcher("variational", max_disparity=64.0)

    def run_sgbm():
        fixed = sgbm.compute(left, right)
        return np.where(fixed >= 0, fixed.astype(np.float32) / 16.0, np.float32(np.nan))

    def run_variational():
        return variational.compute(left, right)

    rows = []
    for name, function in (("StereoSGBM", run_sgbm), ("variational", run_variational)):
        disparity, cold_s = _timed(function)
        warm_s = min(_timed(function)[1] for _ in range(args.repeats))
        returned = known & np.isfinite(disparity)
        errors = truth[returned] - disparity[returned]
        rows.append(
            (
                name,
                cold_s,
                warm_s,
                returned.sum() / known.sum(),
                np.mean(np.abs(errors) > 1.0),
                np.mean(np.abs(errors) > 2.0),
            )
        )

    print(f"{'matcher':12s} {'cold s':>8s} {'warm s':>8s} {'density':>8s} {'bad-1px':>8s} {'bad-2px':>8s}")
    for name, cold_s, warm_s, density, bad1, bad2 in rows:
        print(f"{name:12s} {cold_s:8.3f} {warm_s:8.3f} {density:8.1%} {bad1:8.1%} {bad2:8.1%}")
    (_, sgbm_cold, sgbm_warm, *_), (_, var_cold, var_warm, *_) = rows
    print(f"variational / SGBM time: warm {var_warm / sgbm_warm:.2f}x (goal <= 3x), cold {var_cold / sgbm_cold:.1f}x")


if __name__ == "__main__":
    main()
