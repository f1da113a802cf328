"""Hostile input, round two (issue 25): ROS bags and exports to bags, through the real ``prismap`` in a
subprocess under the address-space limit of ``test_hostile``: exit 2, one line, nothing left behind."""

import pytest
from test_hostile import _prismap, _tree
from test_io_rosbag import LEFT, RIGHT, frames, write_bag  # noqa: F401 (frames is a fixture)

MAP_BAG = ["map", "--bag", "BAG", "--left", LEFT, "--right", RIGHT, "--pose-topic", "/odom", "--voxel", "0.1"]


@pytest.fixture(scope="module")
def bag(frames, tmp_path_factory):  # noqa: F811
    return write_bag(frames, tmp_path_factory.mktemp("bag25") / "rec.bag", "rosbag1")


def _run(argv, tmp_path, **placeholders):
    work = tmp_path / "work"
    work.mkdir(exist_ok=True)
    before = _tree(work)
    argv = [a.replace("WORK", str(work)) for a in argv]
    for name, value in placeholders.items():
        argv = [a.replace(name, str(value)) for a in argv]
    status, stderr = _prismap(argv, tmp_path)
    lines = stderr.strip().splitlines()
    assert status == 2, stderr
    assert len(lines) == 1 and lines[0].startswith(f"prismap {argv[0]}"), stderr
    assert _tree(work) == before
    return lines[0]


@pytest.mark.parametrize("value", ["inf", "1e300", "nan"])
def test_a_pairing_tolerance_beyond_a_day_is_one_line(bag, tmp_path, value):
    """Item 13: inf overflowed converting to nanoseconds (a traceback)."""
    line = _run([*MAP_BAG, "--pair-tolerance", value, "--out", "WORK/o.npz"], tmp_path, BAG=bag)
    assert "--pair-tolerance must lie in (0, 86400] seconds; got" in line
