"""The 3-D viewer: its level-of-detail pyramid and selection against brute force, the command's errors,
and the served page in headless Chromium showing the map's voxels in the colormap's colours."""

import re
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from browser import Browser, find_chromium
from scipy.special import logit

from prismap.cli._main import main
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap
from prismap.io import save_map
from prismap.viewer import (
    AGREEMENT,
    agreement_codes,
    probability_colors,
    select,
    select_codes,
    unobserved_cells,
    voxel_classes,
    voxel_pyramid,
)


def brute_coarse(keys, probability, k):
    """{coarse key: max probability} by a Python dict."""
    out = {}
    for key, p in zip(map(tuple, np.floor_divide(keys, 2**k)), probability):
        out[key] = max(out.get(key, -1.0), p)
    return out


def test_pyramid_levels_hold_the_largest_probability_of_their_voxels():
    rng = np.random.default_rng(3)
    keys = np.unique(rng.integers(-40, 40, size=(3000, 3)), axis=0)  # unique, as a map's keys are
    probability = rng.random(len(keys)).astype(np.float32)
    levels = voxel_pyramid(keys, probability, 0.1, min_voxels=50)
    assert [lv.level for lv in levels] == list(range(len(levels))) and len(levels) >= 4
    for level in levels:
        expected = brute_coarse(keys, probability, level.level)
        assert level.size_m == pytest.approx(0.1 * 2**level.level)
        assert dict(zip(map(tuple, level.keys), level.probability)) == expected
        np.testing.assert_allclose(level.centers_w, (level.keys + 0.5) * level.size_m, rtol=1e-6)
    with pytest.raises(PrismapInputError, match="`keys` must be"):
        voxel_pyramid(keys[:, :2], probability, 0.1)


def test_selection_by_threshold_class_height_and_budget():
    keys = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 5], [2, 2, 2], [3, 3, 3]])
    probability = np.array([0.9, 0.2, 0.95, 0.5, 0.35])
    assert voxel_classes(probability, 0.4, 0.6).tolist() == [2, 0, 2, 1, 0]
    levels = voxel_pyramid(keys, probability, 1.0, min_voxels=1)
    level, mask = select(levels, classes=("occupied",), free_threshold=0.4, occupied_threshold=0.6)
    assert level.level == 0 and level.keys[mask].tolist() == [[0, 0, 0], [0, 0, 5]]
    _, mask = select(levels, classes=("occupied",), z_range_m=(-1, 2), free_threshold=0.4, occupied_threshold=0.6)
    assert levels[0].keys[mask].tolist() == [[0, 0, 0]]
    _, mask = select(levels, threshold=0.3, classes=("free", "unknown"), free_threshold=0.4, occupied_threshold=0.6)
    assert levels[0].keys[mask].tolist() == [[2, 2, 2], [3, 3, 3]]
    level, mask = select(levels, classes=("free", "unknown", "occupied"), budget=3)  # 5 voxels -> coarser
    assert level.level >= 1 and mask.sum() <= 3
    with pytest.raises(PrismapInputError, match="`classes` must be among"):
        select(levels, classes=("maybe",))


def test_unobserved_cells_fill_the_box_around_the_known_voxels():
    keys = np.array([[0, 0, 0], [3, 1, 1]])
    base = voxel_pyramid(keys, np.array([0.9, 0.1]), 0.5)[0]
    cells = unobserved_cells(base)
    box = {(x, y, z) for x in range(4) for y in range(2) for z in range(2)}
    assert set(map(tuple, cells.keys)) == box - {(0, 0, 0), (3, 1, 1)}
    coarse = unobserved_cells(base, budget=4)  # the 16-cell box does not fit: 2x coarser, (0,0,0) and (1,0,0)
    assert coarse.size_m == 1.0 and len(coarse.keys) == 0  # both hold a known voxel


def test_colormap_endpoints_are_viridis():
    np.testing.assert_array_equal(probability_colors([0.0, 1.0]), [[68, 1, 84], [253, 231, 37]])


def test_view_refuses_bad_inputs(tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing.npz")]) == 2
    assert "no such map file" in capsys.readouterr().err
    path = small_map(tmp_path)
    assert main(["view", str(path), "--port", "70000"]) == 2
    assert "--port must lie in [0, 65535]" in capsys.readouterr().err
    assert main(["view", str(path), "--poses", str(tmp_path / "nowhere")]) == 2
    assert "no such sequence folder or pose file" in capsys.readouterr().err
    assert main(["view", str(path), "--colour", "agreement", "--port", "0"]) == 2
    assert "colouring by agreement needs the ground truth (--gt TRUTH.npz)" in capsys.readouterr().err


OUR_CHECKBOXES = "[...document.querySelectorAll('input[type=checkbox]')].filter(e => !e.id.startsWith('mantine-'))"
"""The viewer's own checkboxes in the page (viser's settings panel has its own, with mantine ids)."""

PROBABILITIES = {"high": 0.95, "mid": 0.62, "free": 0.08}


def small_map(tmp_path):
    """Two occupied walls (P 0.95 and 0.62) and a free floor (P 0.08), 0.1 m voxels, 2x2 m each."""
    grid = OccupancyMap(0.1, p0=0.5)
    a, b = np.meshgrid(np.arange(20), np.arange(20), indexing="ij")
    a, b = a.ravel(), b.ravel()
    walls = {
        "high": np.c_[a, np.full_like(a, 20), b],
        "mid": np.c_[np.full_like(a, 20), a, b],
        "free": np.c_[a, b, np.zeros_like(a)],
    }
    for name, keys in walls.items():
        grid.set_voxels(keys, np.full(len(keys), logit(PROBABILITIES[name]), np.float32), np.ones(len(keys), np.uint16))
    path = tmp_path / "map.npz"
    save_map(grid, path)
    return path


def colour_pixels(png, probability, tolerance=6):
    """Pixels within ``tolerance`` (per channel) of the colormap's colour at ``probability``."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1].astype(int)
    colour = probability_colors([probability])[0].astype(int)
    return int((np.abs(image - colour).max(axis=2) <= tolerance).sum())


def wait_for_colours(browser, wanted, timeout_s=40.0):
    """Screenshots until every colour of ``wanted`` covers enough pixels; the last screenshot and counts."""
    deadline = time.monotonic() + timeout_s
    while True:
        png = browser.screenshot()
        counts = {name: colour_pixels(png, PROBABILITIES[name]) for name in PROBABILITIES}
        if all(counts[name] > 2000 for name in wanted) or time.monotonic() > deadline:
            return png, counts
        time.sleep(0.5)


@pytest.fixture
def chromium():
    if find_chromium() is None:
        reason = "no chromium on PATH (.ci/run installs Debian's chromium; install it to run the browser tests)"
        print(reason)
        pytest.skip(reason)


def test_view_serves_the_map_in_the_colormap_colours(tmp_path, chromium):
    path = small_map(tmp_path)
    command = [
        sys.executable,
        "-c",
        "import sys; from prismap.cli import main; sys.exit(main())",
        "view",
        str(path),
        "--port",
        "0",
    ]
    server = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={"PATH": "/usr/bin:/bin", "PYTHONPATH": ":".join(sys.path), "PRISMAP_PROGRESS": "0"},
    )
    try:
        url = None
        for line in server.stdout:
            match = re.search(r"open (http://\S+)", line)
            if match:
                url = match.group(1)
                break
        assert url, "prismap view printed no address"
        with Browser() as browser:
            browser.goto(url)
            browser.wait_for(f"{OUR_CHECKBOXES}.length >= 3")
            png, counts = wait_for_colours(browser, ("high", "mid"))
            Path(tmp_path / "viewer.png").write_bytes(png)
            assert counts["high"] > 2000 and counts["mid"] > 2000, counts  # both occupied walls drawn
            assert counts["free"] < 50, counts  # the free floor is toggled off by default
            browser.evaluate(f"{OUR_CHECKBOXES}[2].click()")  # occupied, unknown, free
            png, counts = wait_for_colours(browser, ("high", "mid", "free"))
            assert counts["free"] > 2000, counts
            assert browser.console_errors == []
    finally:
        server.kill()
        server.wait(timeout=10)


def test_agreement_codes_match_a_voxel_by_voxel_reading_and_danger_survives_coarsening():
    from prismap.io import GroundTruthOccupancy

    rng = np.random.default_rng(7)
    keys = np.unique(rng.integers(-6, 6, size=(400, 3)), axis=0)
    probability = rng.choice([0.1, 0.3, 0.5, 0.8, 0.95], size=len(keys))
    truth_occupied = keys[rng.random(len(keys)) < 0.4]
    observed = keys[rng.random(len(keys)) < 0.7]
    truth = GroundTruthOccupancy(0.1, truth_occupied, np.unique(np.concatenate([observed, truth_occupied[:5]]), axis=0))
    codes = agreement_codes(keys, probability, truth, free_threshold=0.2, occupied_threshold=0.7)
    occupied = set(map(tuple, truth.occupied_keys))
    seen = set(map(tuple, truth.observed_keys))
    names = []
    for key, p in zip(map(tuple, keys), probability):
        state = "free" if p < 0.2 else "occupied" if p >= 0.7 else "undecided"
        if key not in seen or state == "undecided":
            names.append(AGREEMENT[0])
        elif key in occupied:
            names.append("correct occupied" if state == "occupied" else "occupied called free (danger)")
        else:
            names.append("correct free" if state == "free" else "free called occupied")
    assert [AGREEMENT[c] for c in codes] == names
    assert set(codes) == set(range(len(AGREEMENT)))  # every case is exercised
    # a coarse voxel holding a danger voxel shows the danger; the selection counts agree with brute force
    pyramid = voxel_pyramid(keys, codes, 0.1, min_voxels=1)
    level, mask = select_codes(pyramid, shown=(4,), budget=int(np.sum(codes == 4)) - 1)  # too many at full size
    danger = {key for key, c in brute_coarse(keys, codes, level.level).items() if c == 4}
    assert level.level >= 1 and set(map(tuple, level.keys[mask])) == danger
    level, mask = select_codes(pyramid, shown=(2, 3), z_range_m=(0.0, 0.3))
    expected = [(c in (2, 3)) and 0.0 <= (k[2] + 0.5) * 0.1 <= 0.3 for k, c in zip(keys, codes)]
    assert level.level == 0 and mask.tolist() == expected
