"""``prismap demo --quick`` end to end, and ``prismap experiment`` through the command line."""

import re

import pytest

from prismap.cli._main import main


def test_quick_demo_links_only_files_that_exist(tmp_path, capsys):
    out = tmp_path / "outputs"
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    index = (out / "index.md").read_text()
    links = re.findall(r"\]\(([^)]+)\)", index)
    assert len(links) >= 3 * 3 + 3 * 5  # 3 characterisations x 3 files; per experiment table, JSON, 3 figures
    for link in links:
        assert (out / link).is_file(), link
    for needed in ("characterise/sgbm/table.md", "office2d/results.md", "scene3d/results.md",
                   "scene3d/sgbm/characterisation/table.md", "office2d/map_slices_known-mixture.png",
                   "street3d/results.md", "street3d/map_slices_sgbm.png"):
        assert needed in links
    assert "PRISM Brier" in index and "Run time:" in index
    assert "wrote" in capsys.readouterr().out


def test_experiment_command_rejects_bad_options(tmp_path, capsys):
    assert main(["experiment", "--world", "office2d", "--out", str(tmp_path), "--frames", "0", "--quick"]) == 2
    assert "`n_frames` must be a positive integer" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["experiment", "--world", "mars", "--out", str(tmp_path)])
