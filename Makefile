# Two commands set everything up on a fresh machine: `make bench` and `make test`; `make docs` builds the site.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# The CPU build of torch: a local wheel folder when the machine has one, else PyTorch's CPU index.
TORCH_WHEELS ?= /opt/wheels
PIP_FLAGS := -c constraints.txt $(if $(wildcard $(TORCH_WHEELS)),--find-links $(TORCH_WHEELS),--extra-index-url https://download.pytorch.org/whl/cpu)
STAMP := $(VENV)/.installed

.PHONY: bench test perf install clean docs

$(STAMP): setup.cfg constraints.txt pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q $(PIP_FLAGS) -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

bench: $(STAMP)
	$(BIN)/ftcgym bench

test: $(STAMP)
	$(BIN)/ruff check ftcgym tests
	$(BIN)/python -m pytest -n 2 -q

perf: $(STAMP)
	$(BIN)/ftcgym perf

docs: $(STAMP)
	$(BIN)/python -m pip install -q $(PIP_FLAGS) -e '.[docs]'
	$(BIN)/mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) bench_out .pytest_cache site
