"""The README as a newcomer reads it: short, and every command in it runs as written.

The commands are extracted from its ``bash`` blocks. The cheap ones run here: ``prismap --help`` and the three
commands on your own data (with a small synthetic sequence as PATH and SEQ; ``prismap view`` serves until
interrupted, so it is parsed, and the viewer has its own tests). The rest are checked against what they name
(Makefile targets, the venv's folder, pyproject extras) and run by ``.ci/run``: the first run there, from the
built wheel, ``make test`` and ``make demo`` (too long for the suite).
"""

import re
import shlex
import tomllib
from pathlib import Path

import pytest

from prismap.cli._main import build_parser, main
from support import synthetic_sequence

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
MAX_CHARACTERS = 6000


def readme_commands():
    """Every line of the README's ``bash`` blocks, split as the shell would."""
    blocks = re.findall(r"```bash\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.DOTALL)
    return [shlex.split(line, comments=True) for block in blocks for line in block.splitlines() if line.strip()]


def test_the_readme_is_short_and_in_the_issues_order():
    text = README.read_text(encoding="utf-8")
    assert len(text) <= MAX_CHARACTERS, f"README.md has {len(text)} characters; at most {MAX_CHARACTERS}"
    headings = re.findall(r"(?m)^## (.+)$", text)
    assert headings == [
        "Install",
        "First run",
        "Your own data",
        "Results",
        "The whole story, and the tests",
        "Documentation",
        "Citing",
        "Licence",
    ]
    picture = re.search(r"!\[[^]]+\]\(([^)]+)\)", text).group(1)
    assert text.index(picture) < text.index("## Install") and (ROOT / picture).is_file()
    for link in re.findall(r"\]\(([^)#]+)\)", text):
        assert (ROOT / link).exists(), link


def test_every_readme_command_names_something_that_exists():
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    seen = set()
    for argv in readme_commands():
        seen.add(argv[0])
        if argv[0] == "make":
            assert re.search(rf"(?m)^{argv[1]}:", makefile), f"no Makefile target {argv[1]!r}"
            if argv[1] != "install":  # every make target but install (which they all run) is run by .ci/run
                assert f"make {argv[1]}" in ci, f".ci/run does not run make {argv[1]}"
        elif argv[0] == "source":
            assert argv[1] == ".venv/bin/activate" and re.search(r"(?m)^VENV\s*:= \.venv$", makefile)
        elif argv[:3] == ["pip", "install", "-e"]:
            extra = re.fullmatch(r"\.\[(\w+)\]", argv[3]).group(1)
            assert extra in extras, f"pyproject.toml has no extra {extra!r}"
        elif argv[0] == "prismap":
            if argv[1:] != ["--help"]:
                build_parser().parse_args(argv[1:])  # exits 2 on an option the parser does not know
            if argv[1:3] == ["demo", "--quick"]:
                assert shlex.join(argv) in ci, ".ci/run does not run the README's first run"
        else:
            pytest.fail(f"the README runs {shlex.join(argv)!r}, which this test does not know")
    assert seen == {"make", "source", "pip", "prismap"}


def test_prismap_help_runs(capsys):
    assert ["prismap", "--help"] in readme_commands()
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0 and "characterise" in capsys.readouterr().out


def test_the_own_data_commands_run_as_written(tmp_path, monkeypatch, capsys):
    sequence = synthetic_sequence(tmp_path / "data", n_frames=3)
    commands = [argv for argv in readme_commands() if argv[:2] in (["prismap", "characterise"], ["prismap", "map"])]
    assert [argv[1] for argv in commands] == ["characterise", "map"]
    monkeypatch.chdir(tmp_path)
    for argv in commands:
        argv = [str(sequence) if word in ("PATH", "SEQ") else word for word in argv]
        assert main(argv[1:]) == 0, shlex.join(argv)
    printed = capsys.readouterr().out
    assert (tmp_path / "model" / "error_model.json").is_file() and (tmp_path / "map.npz").is_file()
    assert "reproduce with: prismap map --sequence" in printed and (tmp_path / "map.run.json").is_file()
    assert ["prismap", "view", "map.npz"] in readme_commands()
