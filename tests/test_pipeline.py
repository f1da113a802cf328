"""The mapping pipeline: configs, sensor models for a camera, sequence runs against hand loops, checkpoints,
LiDAR reference maps."""

import pickle
import threading

import cv2
import numpy as np
import pytest

from prismap.camera import integrate_disparity
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap
from prismap.io import load_map, read_ground_truth, read_sequence, write_ground_truth, write_sequence
from prismap.pipeline import (
    DisparitySource,
    build_sensor_model,
    ground_truth_from_map,
    integrate_frames,
    lidar_reference_map,
    map_sequence,
    remove_checkpoint,
)
from prismap.pipeline._prefetch import THREAD_NAME, Prefetch
from prismap.sensor_models import AndertModel, ConvolutionModel, PrismModel
from prismap.stereo import make_matcher
from support import CAMERA, MIXTURE, assert_same_map, config, synthetic_sequence


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("pipeline") / "seq")


def hand_map(sequence_dir, cfg, indices, disparity_of):
    """The reference: a plain loop of OccupancyMap.integrate_disparity over the frames."""
    sequence = read_sequence(sequence_dir)
    model = build_sensor_model(
        cfg.model,
        sequence.camera,
        voxel_size_m=cfg.voxel_size_m,
        p0=cfg.p0,
        error_model=cfg.error_model,
        **cfg.model_options,
    )
    grid = OccupancyMap(cfg.voxel_size_m, p0=cfg.p0)
    for index in indices:
        frame = sequence[index]
        integrate_disparity(
            grid,
            disparity_of(frame),
            sequence.camera,
            frame.T_world_cam,
            model,
            mode=cfg.mode,
            policy=cfg.policy,
            max_range_m=cfg.max_range_m,
            subsample=cfg.subsample,
        )
    return grid


# ------------------------------------------------------------------------------------ sensor models
def test_dominant_sigma_is_the_largest_weight_component():
    assert MIXTURE.dominant_sigma() == 0.4
    assert GaussianMixture([0.3, 0.7], [0, 0], [0.2, 1.5]).dominant_sigma() == 1.5


def test_build_sensor_model_gives_each_model_its_noise():
    prism = build_sensor_model("prism", CAMERA, voxel_size_m=0.1, p0=0.05, error_model=MIXTURE)
    assert isinstance(prism, PrismModel) and prism.error_model is MIXTURE
    assert prism.focal_baseline == pytest.approx(7.2) and prism.voxel_size_m == 0.1 and prism.p0 == 0.05
    conv = build_sensor_model("convolution", CAMERA, voxel_size_m=0.1, p0=0.05, error_model=MIXTURE)
    assert isinstance(conv, ConvolutionModel) and conv.sigma_px == 0.4
    andert = build_sensor_model(
        "andert", CAMERA, voxel_size_m=0.1, p0=0.05, error_model=MIXTURE, sigma_px=1.25, eta=0.2
    )
    assert isinstance(andert, AndertModel) and andert.sigma_px == 1.25 and andert.eta == 0.2
    ideal = build_sensor_model("ideal", CAMERA, voxel_size_m=0.1, p0=0.05)  # needs no error model
    assert ideal.name == "ideal"


@pytest.mark.parametrize(
    ("name", "params", "message"),
    [
        ("prism", {}, "'prism' needs an error model"),
        ("andert", {}, "needs an error model (`error_model`) or an explicit sigma_px"),
        ("hitmiss", {"sigma_px": 1.0}, "sensor model 'hitmiss': bad parameter(s) ['sigma_px']"),
        ("octree", {}, "unknown sensor model 'octree'"),
    ],
)
def test_build_sensor_model_errors_name_the_problem(name, params, message):
    with pytest.raises(
        PrismapInputError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]")
    ):
        build_sensor_model(name, CAMERA, voxel_size_m=0.1, p0=0.05, **params)


# ----------------------------------------------------------------------------------------- configs
def test_config_is_hashable_picklable_and_fingerprinted_by_content():
    a = config(model_params={"alpha_m": 0.3, "p_occ": 0.9})
    b = config(model_params={"p_occ": 0.9, "alpha_m": 0.3})
    assert a == b and hash(a) == hash(b) and a.fingerprint() == b.fingerprint()
    assert config(error_model=GaussianMixture([0.8, 0.2], [0.05, -0.3], [0.4, 2.5])) == config()
    assert pickle.loads(pickle.dumps(a)) == a
    assert a.model_options == {"alpha_m": 0.3, "p_occ": 0.9}
    assert config(voxel_size_m=0.25).fingerprint() != a.fingerprint()
    assert config(error_model=GaussianMixture.gaussian(0.41)).fingerprint() != config().fingerprint()
    # floor sampling changes a ray-mode map (a checkpoint of another floor_rays is not resumed), not a projective one
    assert config(floor_rays=0).fingerprint() != config().fingerprint()
    assert config(mode="projective", floor_rays=0) == config(mode="projective")


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"voxel_size_m": 0}, "`voxel_size_m` must be a finite number > 0"),
        ({"p0": 1.0}, r"`p0` must lie in \(0, 1\)"),
        ({"mode": "octree"}, "`mode` must be one of"),
        ({"policy": "vote"}, "`policy` must be one of"),
        ({"subsample": 0}, "`subsample` must be an integer >= 1"),
        ({"subsample": "a"}, "`subsample` must be an integer >= 1; got 'a'"),
        ({"subsample": 1.5}, "`subsample` must be an integer >= 1; got 1.5"),
        ({"floor_rays": -1}, r"`floor_rays` must be an integer >= 0 \(0: every ray\); got -1"),
        ({"floor_rays": 2.5}, "`floor_rays` must be an integer >= 0"),
        ({"frames": (3, 3)}, "`frames` 3:3 is empty"),
        ({"frames": (-1, None)}, "`frames` must hold integers >= 0"),
        ({"matcher": "census"}, "unknown matcher 'census'"),
        ({"max_range_m": -2}, "`max_range_m` must be a finite number > 0"),
    ],
)
def test_config_rejects_bad_values(changes, message):
    with pytest.raises(PrismapInputError, match=message):
        config(**changes)


def test_frame_range_beyond_the_sequence_is_an_error(sequence_dir):
    with pytest.raises(PrismapInputError, match="frames 10: select no frame of a sequence of 6 frames"):
        map_sequence(sequence_dir, config(frames=(10, None)))


# -------------------------------------------------------------------------------------------- runs
def test_sequence_run_equals_a_hand_loop_over_ground_truth_disparity(sequence_dir):
    cfg = config(frames=(1, 5), policy="max-abs")
    grid = map_sequence(sequence_dir, cfg, progress=False)
    assert grid.n_frames == 4 and grid.policies == ("max-abs",)
    assert_same_map(grid, hand_map(sequence_dir, cfg, range(1, 5), lambda f: f.disparity_gt))


def test_matcher_run_equals_a_hand_loop_over_matched_disparity(sequence_dir):
    cfg = config(
        disparity_source="matcher",
        matcher="bm",
        matcher_params={"num_disparities": 16, "block_size": 7},
        model="ideal",
        error_model=None,
        subsample=2,
    )
    matcher = make_matcher("bm", num_disparities=16, block_size=7)
    grid = map_sequence(sequence_dir, cfg, progress=False)
    assert_same_map(grid, hand_map(sequence_dir, cfg, range(6), lambda f: matcher.compute(f.left, f.right)))


def test_a_disparity_directory_gives_the_map_of_the_sequences_own_disparities(sequence_dir, tmp_path):
    for name in read_sequence(sequence_dir).names:
        assert cv2.imwrite(str(tmp_path / name), cv2.imread(str(sequence_dir / "disp" / name), cv2.IMREAD_UNCHANGED))
    by_dir = map_sequence(sequence_dir, config(disparity_source=str(tmp_path), frames=(0, 3)), progress=False)
    assert_same_map(by_dir, map_sequence(sequence_dir, config(frames=(0, 3)), progress=False))
    (tmp_path / read_sequence(sequence_dir).names[1]).unlink()
    with pytest.raises(PrismapInputError, match="000001.png: disparity file missing"):
        map_sequence(sequence_dir, config(disparity_source=str(tmp_path), frames=(0, 3)), progress=False)


def test_disparity_source_errors(sequence_dir, tmp_path):
    with pytest.raises(PrismapInputError, match="disparity directory .*nowhere: not found"):
        DisparitySource(read_sequence(sequence_dir), config(disparity_source=str(tmp_path / "nowhere")))
    with pytest.raises(PrismapInputError, match="matcher 'sgbm': bad parameter"):
        DisparitySource(read_sequence(sequence_dir), config(disparity_source="matcher", matcher_params={"speed": 3}))


def test_a_sequence_without_poses_is_refused(sequence_dir, tmp_path):
    frames = [f for f in read_sequence(sequence_dir)][:2]
    unposed = [type(f)(f.left, f.right, f.camera, f.disparity_gt) for f in frames]
    write_sequence(unposed, tmp_path / "unposed")
    with pytest.raises(PrismapInputError, match="no poses.txt; mapping needs the pose of every frame"):
        map_sequence(tmp_path / "unposed", config(), progress=False)


# -------------------------------------------------------------------------------------- look-ahead
def prefetch_threads():
    return [thread for thread in threading.enumerate() if thread.name.startswith(THREAD_NAME)]


def test_prefetch_gives_every_item_in_order_computing_at_most_one_ahead():
    calls, seen = [], []
    with Prefetch(lambda i: calls.append(i) or i * i, range(5)) as items:
        for k, (item, result) in enumerate(items):
            assert len(calls) <= k + 2  # this item and at most the next one
            seen.append((item, result))
    assert seen == [(i, i * i) for i in range(5)] and calls == list(range(5))
    assert prefetch_threads() == []
    with Prefetch(lambda i: i, []) as items:
        assert list(items) == []


def test_prefetch_raises_an_items_error_at_that_item_and_computes_nothing_past_it():
    calls, seen = [], []

    def produce(i):
        calls.append(i)
        if i == 3:
            raise PrismapInputError(f"frame {i}: broken")
        return i

    with pytest.raises(PrismapInputError, match="^frame 3: broken$"), Prefetch(produce, range(6)) as items:
        for item, _ in items:
            seen.append(item)
    assert seen == [0, 1, 2] and calls == [0, 1, 2, 3]
    assert prefetch_threads() == []


def test_leaving_a_prefetch_on_keyboard_interrupt_waits_for_the_running_look_ahead():
    running, finished, calls = threading.Event(), [], []

    def produce(i):
        calls.append(i)
        if i == 2:
            running.set()
            threading.Event().wait(0.05)  # still computing when the caller leaves
            finished.append(i)
        return i

    with pytest.raises(KeyboardInterrupt), Prefetch(produce, range(6)) as items:
        for item, _ in items:
            if item == 1:
                assert running.wait(5)
                raise KeyboardInterrupt
    assert finished == [2] and calls == [0, 1, 2]  # joined, and nothing started after it
    assert prefetch_threads() == []


def test_a_disparity_error_surfaces_at_its_frame_with_the_frames_before_integrated(sequence_dir, tmp_path):
    for name in read_sequence(sequence_dir).names[:3]:
        assert cv2.imwrite(str(tmp_path / name), cv2.imread(str(sequence_dir / "disp" / name), cv2.IMREAD_UNCHANGED))
    cfg = config(disparity_source=str(tmp_path))
    sequence = read_sequence(sequence_dir)
    grid, frames_done = OccupancyMap(cfg.voxel_size_m, p0=cfg.p0), []
    with pytest.raises(PrismapInputError, match=r"000003.png: disparity file missing"):
        integrate_frames(grid, sequence, cfg, range(6), on_frame=lambda g: frames_done.append(g.n_frames))
    assert frames_done == [1, 2, 3] and prefetch_threads() == []
    assert_same_map(grid, hand_map(sequence_dir, cfg, range(3), lambda f: f.disparity_gt))


def test_a_keyboard_interrupt_between_frames_stops_the_look_ahead(sequence_dir, monkeypatch):
    cfg = config(
        disparity_source="matcher",
        matcher="bm",
        matcher_params={"num_disparities": 16, "block_size": 7},
        model="ideal",
        error_model=None,
    )
    computed, original = [], DisparitySource.__call__

    def counted(self, index):
        computed.append(index)
        return original(self, index)

    def interrupt(grid):
        if grid.n_frames == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(DisparitySource, "__call__", counted)
    grid = OccupancyMap(cfg.voxel_size_m, p0=cfg.p0)
    with pytest.raises(KeyboardInterrupt):
        integrate_frames(grid, read_sequence(sequence_dir), cfg, range(6), on_frame=interrupt)
    assert grid.n_frames == 2 and computed == [0, 1, 2] and prefetch_threads() == []


# ------------------------------------------------------------------------------------- checkpoints
class _Killed(Exception):
    pass


def test_a_run_interrupted_after_a_checkpoint_resumes_to_the_uninterrupted_map(sequence_dir, tmp_path, monkeypatch):
    cfg = config()
    checkpoint = tmp_path / "run.checkpoint.npz"
    whole = map_sequence(sequence_dir, cfg, progress=False)
    original = DisparitySource.__call__

    def dies_at_frame_5(self, index):
        if index == 5:
            raise _Killed
        return original(self, index)

    monkeypatch.setattr(DisparitySource, "__call__", dies_at_frame_5)
    with pytest.raises(_Killed):
        map_sequence(sequence_dir, cfg, progress=False, checkpoint=checkpoint, checkpoint_every=2)
    assert read_checkpoint_frames(checkpoint) == 4  # saved after frames 2 and 4; frame 5 never arrived
    monkeypatch.setattr(DisparitySource, "__call__", original)
    resumed = map_sequence(sequence_dir, cfg, progress=False, checkpoint=checkpoint, checkpoint_every=2)
    assert_same_map(resumed, whole)  # exact: the checkpoint stores float32 log-odds losslessly
    remove_checkpoint(checkpoint)
    assert list(tmp_path.iterdir()) == []


def read_checkpoint_frames(checkpoint):
    return load_map(checkpoint).n_frames


def test_a_checkpoint_of_another_configuration_is_refused(sequence_dir, tmp_path):
    checkpoint = tmp_path / "run.checkpoint.npz"
    map_sequence(sequence_dir, config(frames=(0, 3)), progress=False, checkpoint=checkpoint, checkpoint_every=1)
    assert read_checkpoint_frames(checkpoint) == 2
    with pytest.raises(PrismapInputError, match="written by a run with another configuration or other input"):
        map_sequence(sequence_dir, config(frames=(0, 3), p0=0.1), progress=False, checkpoint=checkpoint)
    (tmp_path / "run.checkpoint.json").unlink()
    with pytest.raises(PrismapInputError, match="has no run.checkpoint.json to say which run wrote it"):
        map_sequence(sequence_dir, config(frames=(0, 3)), progress=False, checkpoint=checkpoint)


# ------------------------------------------------------------------------------------------- LiDAR
def _wall_scan(origin, n=25):
    """Points of the wall x = 5.05 m (mid-voxel at 0.1 m) seen from ``origin`` over a 40x40 degree fan."""
    yaw, pitch = np.meshgrid(np.radians(np.linspace(-20, 20, n)), np.radians(np.linspace(-20, 20, n)))
    directions = np.stack([np.ones_like(yaw), np.tan(yaw), np.tan(pitch)], axis=-1).reshape(-1, 3)
    distance = (5.05 - origin[0]) / directions[:, 0]
    return origin + directions * distance[:, None]


def test_lidar_reference_map_marks_exactly_the_voxels_of_the_scanned_points():
    voxel = 0.1
    origin = np.array([0.02, 0.03, 0.01])
    points_w = _wall_scan(origin)
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(np.array([0.1, -0.2, 0.3]))[0]
    pose[:3, 3] = origin
    points_sensor = (points_w - origin) @ pose[:3, :3]  # the same points in a rotated sensor frame
    grid = lidar_reference_map([(points_sensor, pose)], voxel, progress=False)
    truth = ground_truth_from_map(grid)
    expected = np.unique(np.floor(points_w / voxel).astype(np.int64), axis=0)
    np.testing.assert_array_equal(truth.occupied_keys, expected)
    # every voxel strictly before the wall along a ray is known and free
    halfway = np.unique(np.floor((origin + 0.5 * (points_w - origin)) / voxel).astype(np.int64), axis=0)
    assert np.all(grid.probability_at_keys(halfway) < 0.5) and np.all(grid.lookup_keys(halfway)[1] == 1)
    # free space lies between the sensor and the wall's voxel layer (x key 50); nothing behind it is known
    assert truth.free_keys[:, 0].min() == 0 and truth.free_keys[:, 0].max() == 50


def test_lidar_ground_truth_round_trips_and_scores_its_own_map_perfectly(tmp_path):
    from prismap.evaluate import align_to_ground_truth, score_map

    scans = [(_wall_scan(np.array([0.0, y, 0.0])) - [0.0, y, 0.0], _translation([0.0, y, 0.0])) for y in (-0.5, 0.5)]
    grid = lidar_reference_map(scans, 0.1, progress=False)
    truth = ground_truth_from_map(grid)
    write_ground_truth(tmp_path / "lidar.npz", truth)
    again = read_ground_truth(tmp_path / "lidar.npz")
    np.testing.assert_array_equal(again.occupied_keys, truth.occupied_keys)
    keys = grid.known_voxels()[0]
    probability, occupied = align_to_ground_truth(
        keys, grid.probability_at_keys(keys), again.occupied_keys, again.observed_keys, p0=grid.p0
    )
    scores = score_map(probability, occupied)
    assert scores.occupied_called_free == 0 and scores.free_called_occupied == 0 and scores.roc_auc == 1.0


def _translation(t):
    pose = np.eye(4)
    pose[:3, 3] = t
    return pose


def test_lidar_input_errors():
    with pytest.raises(PrismapInputError, match="`scans` is empty"):
        lidar_reference_map([], 0.1, progress=False)
    with pytest.raises(PrismapInputError, match=r"`scans\[0\]` points must be \(N, 3\) or \(N, 4\)"):
        lidar_reference_map([(np.zeros((4, 2)), np.eye(4))], 0.1, progress=False)
    with pytest.raises(PrismapInputError, match=r"`scans\[0\]` must be a \(points, T_world_sensor\) pair"):
        lidar_reference_map([np.zeros((4, 3))], 0.1, progress=False)


def test_progress_labels_name_the_model_its_variant_and_the_disparities(tmp_path):
    from prismap.characterise import ErrorModel
    from prismap.pipeline import MappingConfig
    from support import MIXTURE, conditioned_error_model

    conditioned = conditioned_error_model(feature="texture", edges=(20.0, 30.0))
    assert isinstance(conditioned, ErrorModel)
    folder = tmp_path / "sgbm" / "disparity"
    folder.mkdir(parents=True)
    cases = [
        (MappingConfig(model="prism", error_model=conditioned), "prism conditioned, sgbm"),
        (MappingConfig(model="prism", error_model=conditioned, conditioned=False, matcher="bm"), "prism plain, bm"),
        (
            MappingConfig(model="convolution", error_model=MIXTURE, disparity_source="sequence"),
            "convolution plain, the sequence's disparities",
        ),
        (
            MappingConfig(model="hitmiss", error_model=conditioned, conditioned=False, disparity_source=str(folder)),
            "hitmiss, disparities from sgbm/disparity",
        ),
    ]
    assert [config.label for config, _ in cases] == [label for _, label in cases]
