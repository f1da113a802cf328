# A fresh machine needs Python >= 3.11 and PyPI:  `make install`, then `source .venv/bin/activate`.
# Every target creates .venv if it is missing and (re)installs prismap when pyproject.toml changes.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.prismap-installed
DOCS_STAMP := $(VENV)/.prismap-docs-installed
OUT    ?= outputs

.PHONY: install demo test docs dist bench clean-numba clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e ".[test,docs,dist]"
	touch $(DOCS_STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/prismap demo --out $(OUT)

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile

# The documentation site, warnings as errors: docs/_build/html/index.html
docs: $(DOCS_STAMP)
	$(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html

# The wheel and sdist in dist/, their metadata checked
dist: $(DOCS_STAMP)
	rm -rf dist
	$(PY) -m build --outdir dist .
	$(PY) -m twine check --strict dist/*

bench: $(STAMP)
	for f in benchmarks/bench_*.py; do $(PY) $$f || exit 1; done

clean-numba:
	find src -name '*.nbi' -delete -o -name '*.nbc' -delete

clean:
	rm -rf $(VENV) $(OUT) build dist src/*.egg-info .pytest_cache docs/_build docs/_generated docs/auto_examples
