"""Progress: a tqdm bar on a terminal, plain lines (every ~10 %, elapsed and time left) without one."""

import io
import re
import subprocess
import sys

import pytest
from tqdm.auto import tqdm

from prismap import _progress
from prismap._progress import LineProgress, progress, progress_mode


class FakeTty(io.StringIO):
    def isatty(self):
        return True


class Clock:
    """A clock that advances one second per reading after the first."""

    def __init__(self):
        self.t = -1.0

    def __call__(self):
        self.t += 1.0
        return self.t


@pytest.mark.parametrize(
    ("env", "stream", "expected"),
    [
        (None, FakeTty(), "bar"),
        (None, io.StringIO(), "lines"),
        ("0", FakeTty(), "off"),
        ("lines", FakeTty(), "lines"),
        ("bar", io.StringIO(), "bar"),
        ("1", io.StringIO(), "bar"),
    ],
)
def test_mode_follows_the_terminal_unless_the_environment_says(monkeypatch, env, stream, expected):
    if env is None:
        monkeypatch.delenv("PRISMAP_PROGRESS", raising=False)
    else:
        monkeypatch.setenv("PRISMAP_PROGRESS", env)
    assert progress_mode(stream=stream) == expected
    assert progress_mode(False, stream=stream) == "off"


def test_a_terminal_gets_a_tqdm_bar_and_a_pipe_gets_lines(monkeypatch):
    monkeypatch.delenv("PRISMAP_PROGRESS", raising=False)
    tty = FakeTty()
    monkeypatch.setattr(_progress.sys, "stderr", tty)
    bar = progress(range(3), desc="work")
    assert isinstance(bar, tqdm) and not bar.disable
    assert list(bar) == [0, 1, 2]
    assert "work" in tty.getvalue()
    monkeypatch.setattr(_progress.sys, "stderr", io.StringIO())
    assert isinstance(progress(range(3)), LineProgress)


def test_lines_every_ten_percent_with_elapsed_and_time_left():
    out = io.StringIO()
    items = list(LineProgress(range(20), desc="map prism", unit="frame", stream=out, clock=Clock()))
    assert items == list(range(20))
    lines = out.getvalue().splitlines()
    done = [int(re.match(r"map prism: (\d+)/20 frames", line).group(1)) for line in lines]
    assert done == [1] + list(range(2, 21, 2))  # the first frame, then every 10 %
    # clock: start 0, then 1 s per reading -> k-th line at k s; time left = elapsed / n * (20 - n)
    assert lines[0] == "map prism: 1/20 frames (5%), 1.0 s elapsed, ~19.0 s left"
    assert lines[-1] == "map prism: 20/20 frames (100%), 11.0 s elapsed, ~0.0 s left"


def test_lines_by_update_without_total_and_long_durations():
    out = io.StringIO()
    with LineProgress(desc="steps", unit="step", stream=out, clock=lambda: 0.0) as bar:
        for _ in range(5):
            bar.update()
    assert [line.split(":")[1].split()[0] for line in out.getvalue().splitlines()] == ["1", "2", "4"]
    assert bar.n == 5
    assert _progress._duration(125) == "2 min 05 s" and _progress._duration(3725) == "1 h 02 min"


def test_a_piped_command_prints_progress_lines(tmp_path):
    code = "from prismap._progress import progress\nfor _ in progress(range(4), desc='demo', unit='step'): pass\n"
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": ":".join(sys.path)}
    result = subprocess.run(
        [sys.executable, "-c", code], check=False, capture_output=True, text=True, env=env, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert [line.split(" (")[0] for line in result.stderr.splitlines()] == [
        "demo: 1/4 steps",
        "demo: 2/4 steps",
        "demo: 3/4 steps",
        "demo: 4/4 steps",
    ]


def test_weighted_lines_estimate_from_the_work_done_not_the_count():
    # 3 cheap steps then one that costs 7 times their sum: after the cheap ones 30 % is done, not 75 %
    out = io.StringIO()
    items = list(LineProgress("abcd", desc="demo", unit="step", stream=out, clock=Clock(), weights=[1, 1, 1, 7]))
    assert items == list("abcd")
    lines = out.getvalue().splitlines()
    # clock: start 0, the k-th line at k s; time left = elapsed / done * (1 - done)
    assert lines[2] == "demo: 3/4 steps (30% of the work), 3.0 s elapsed, ~7.0 s left"
    assert lines[3] == "demo: 4/4 steps (100% of the work), 4.0 s elapsed, ~0.0 s left"


@pytest.mark.parametrize(("weights", "message"), [([1, 0], "finite and > 0"), ([1, 2, 3], "one weight per item")])
def test_bad_weights_are_refused(weights, message):
    with pytest.raises(ValueError, match=message):
        LineProgress(range(2), weights=weights, stream=io.StringIO())


def test_a_weighted_bar_moves_by_weight(monkeypatch):
    monkeypatch.setenv("PRISMAP_PROGRESS", "bar")
    tty = FakeTty()
    monkeypatch.setattr(_progress.sys, "stderr", tty)
    bar = progress(range(3), desc="demo", weights=[1, 2, 7])
    seen = [(item, bar._bar.n) for item in bar]
    assert seen == [(0, 0), (1, 1.0), (2, 3.0)] and bar._bar.n == 10.0
    assert "% of the work" in tty.getvalue()
