# Two commands for a newcomer: `make run` (the main job) and `make test` (the whole suite).
# Both create .venv with pip when it is missing and install the project into it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run example walkthrough figure test lint bench clean browser

$(STAMP): pyproject.toml docker/constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c docker/constraints.txt -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(PY) -m canal_service

example: $(STAMP)
	$(PY) examples/quickstart.py

walkthrough: $(STAMP)
	$(PY) examples/walkthrough.py

figure: $(STAMP)
	$(PY) examples/render_figure.py

lint: $(STAMP)
	$(PY) -m ruff check canal_core canal_protocol service clients tests bench examples
	$(PY) -m mypy canal_core canal_protocol service/canal_service clients/canal_client

# tests/browser drive Debian's chromium headless (no browser is downloaded at run time)
browser:
	@command -v chromium >/dev/null || command -v chromium-browser >/dev/null || { \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq chromium; }

test: lint browser
	$(PY) -m pytest

bench: $(STAMP)
	$(PY) -m bench

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
