"""``prismap demo --quick`` end to end (its Markdown index and HTML report, loaded in headless Chromium),
the report's Markdown-to-HTML tables, and ``prismap experiment`` through the command line."""

import contextlib
import io
import json
import re

import pytest
from browser import Browser, find_chromium

from prismap.cli._main import main
from prismap.experiment._report import markdown_to_html


@pytest.fixture(scope="module")
def quick_demo(tmp_path_factory):
    """The output folder of one ``prismap demo --quick`` and what it printed."""
    out = tmp_path_factory.mktemp("demo") / "outputs"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(["demo", "--quick", "--out", str(out)]) == 0
    return out, printed.getvalue()


def test_quick_demo_links_only_files_that_exist(quick_demo):
    out, printed = quick_demo
    index = (out / "index.md").read_text()
    links = re.findall(r"\]\(([^)]+)\)", index)
    assert len(links) >= 3 * 3 + 6 + 3 * 5  # 3 characterisations x 3 files, models compare, per experiment 5
    for link in links:
        assert (out / link).is_file(), link
    for needed in (
        "characterise/sgbm/table.md",
        "models/profiles.png",
        "office2d/results.md",
        "scene3d/results.md",
        "scene3d/sgbm/characterisation/table.md",
        "office2d/map_slices_known-mixture.png",
        "street3d/results.md",
        "street3d/map_slices_sgbm.png",
    ):
        assert needed in links
    assert "PRISM Brier" in index and "Run time:" in index and "selected G =" in index
    assert f"wrote {out / 'index.html'}" in printed


def test_markdown_tables_become_html_tables():
    text = "# Title\n\nSome **bold** `x`.\n\n| model | Brier |\n|---|---:|\n| prism | **0.0123** |\n| ideal | n/a |\n"
    assert markdown_to_html(text) == (
        "<h3>Title</h3>\n<p>Some <strong>bold</strong> <code>x</code>.</p>\n"
        "<table><thead><tr><th>model</th><th class=num>Brier</th></tr></thead><tbody>"
        "<tr><td>prism</td><td class=num><strong>0.0123</strong></td></tr>"
        "<tr><td>ideal</td><td class=num>n/a</td></tr></tbody></table>"
    )


def test_html_report_leads_with_the_answer_and_loads_in_chromium(quick_demo, tmp_path):
    out, _ = quick_demo
    page = (out / "index.html").read_text()
    tops = re.findall(r"<h2[^>]*>([^<]+)</h2>", page)
    assert tops == ["Which model wins", "PRISM against OctoMap", "Confident and wrong", "The maps", "Details"]
    titles = re.findall(r'<section id="s\d+"><h3>([^<]+)</h3>', page)  # the steps (tables' own titles are h3 too)
    assert [t.split(". ", 1)[1].split()[0] for t in titles] == ["Stereo", "Sensor", "2-D", "3-D", "Street,"]
    # self-contained: every image embedded, the first of them the 3-D render, then the map slices
    sources = re.findall(r'<img src="([^"]+)"', page)
    assert len(sources) >= 1 + 3 + 3 * 2 + 4 + 3 * 3 and all(s.startswith("data:image/png;base64,") for s in sources)
    assert (out / "map3d.png").is_file() and page.index("map3d.png") < page.index("map_slices")
    # every winner row names a world and matcher of the runs; PRISM against OctoMap for each 3-D world
    summary = page[page.index('id="summary"') : page.index('id="headline"')]
    assert summary.count("<tr>") == 1 + 3 and ">scene3d<" in summary and ">street3d<" in summary
    headline = page[page.index('id="headline"') : page.index('id="maps"')]
    assert ">scene3d<" in headline and ">street3d<" in headline and " vs " in headline
    # each map file linked with the command that opens it; the targets left out; tables folded
    maps = re.findall(r'<a href="([^"]+\.npz)">', page)
    assert "scene3d/cells/sgbm__prism_conditioned.npz" in maps and all((out / m).is_file() for m in maps)
    assert (
        f"prismap view {out}/scene3d/cells/sgbm__prism_conditioned.npz --gt {out}/scene3d/sequence/occupancy.npz"
        in page
    )
    assert "Targets" not in page and "NOT MET" not in page and page.count("<details>") >= 3 + 3
    folded = re.findall(r"<details><summary>(.*?)</summary>", page)
    assert any("thesis tables 3.1-3.3" in f for f in folded) and "PRISM Brier" in page
    if find_chromium() is None:
        reason = "no chromium on PATH (.ci/run installs Debian's chromium; install it to run the browser tests)"
        print(reason)
        pytest.skip(reason)
    with Browser(width=1100, height=1400) as browser:
        browser.goto((out / "index.html").as_uri())
        browser.wait_for("document.readyState === 'complete' && [...document.images].every(i => i.complete)")
        broken = browser.evaluate("[...document.images].filter(i => !(i.naturalWidth > 0)).map(i => i.src)")
        assert broken == []
        assert browser.evaluate("document.images.length") == len(sources)
        assert browser.evaluate("document.querySelectorAll('table tbody tr').length") > 20
        (tmp_path / "report.png").write_bytes(browser.screenshot())
        assert browser.console_errors == []


def test_experiment_command_rejects_bad_options(tmp_path, capsys):
    assert main(["experiment", "--world", "office2d", "--out", str(tmp_path), "--frames", "0", "--quick"]) == 2
    assert "`n_frames` must be a positive integer" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["experiment", "--world", "mars", "--out", str(tmp_path)])


def test_each_3d_map_of_the_demo_names_the_command_that_makes_it_again(quick_demo, tmp_path):
    import shlex

    from prismap.io import load_map
    from support import assert_same_map

    out, _ = quick_demo
    records = sorted((out / "scene3d" / "cells").glob("*.run.json"))
    assert len(records) == len(list((out / "scene3d" / "cells").glob("*.npz"))) >= 2
    assert "sgbm__hitmiss.run.json" in (out / "index.html").read_text()
    record = json.loads((out / "scene3d" / "cells" / "sgbm__hitmiss.run.json").read_text())
    argv = shlex.split(record["command"])
    assert argv[:2] == ["prismap", "map"] and argv[-2:] == [
        "--out",
        str((out / "scene3d/cells/sgbm__hitmiss.npz").resolve()),
    ]
    again = tmp_path / "again.npz"
    assert main(argv[1:-1] + [str(again)]) == 0
    assert_same_map(load_map(again), load_map(out / "scene3d" / "cells" / "sgbm__hitmiss.npz"))
