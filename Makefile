# Everything runs from a project-local virtual environment, created on first use.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test vm vm-load lint bench accuracy docs clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

demo: $(VENV)/.installed
	$(BIN)/stereod demo

test: $(VENV)/.installed
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist loadgroup --durations=15

vm: $(VENV)/.installed
	bash tests/vm/run.sh

vm-load: $(VENV)/.installed
	bash tests/vm/under_load.sh

lint: $(VENV)/.installed
	$(BIN)/ruff check stereod fakes drivers tests benchmarks docs
	$(BIN)/ruff format --check stereod fakes drivers tests benchmarks docs
	$(BIN)/mypy

# Each benchmark writes its tables (and figures) into docs/bench/, which the site includes.
bench: $(VENV)/.installed
	$(BIN)/python benchmarks/throughput.py
	$(BIN)/python benchmarks/throughput.py --color
	$(BIN)/python benchmarks/images.py
	$(BIN)/python benchmarks/people.py

accuracy: $(VENV)/.installed
	$(BIN)/python benchmarks/accuracy.py

# The site, with the reference pages generated from the code, into site/; any warning fails.
$(VENV)/.docs: $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	touch $@

docs: $(VENV)/.docs
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) site build *.egg-info .pytest_cache .mypy_cache .ruff_cache
