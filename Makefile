# Everything runs from a project-local virtual environment, created on first use.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test vm vm-load lint bench accuracy clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

demo: $(VENV)/.installed
	$(BIN)/stereod demo

test: $(VENV)/.installed
	$(BIN)/python -m pytest -q

vm: $(VENV)/.installed
	bash tests/vm/run.sh

vm-load: $(VENV)/.installed
	bash tests/vm/under_load.sh

lint: $(VENV)/.installed
	$(BIN)/ruff check stereod fakes drivers tests benchmarks
	$(BIN)/ruff format --check stereod fakes drivers tests benchmarks
	$(BIN)/mypy

bench: $(VENV)/.installed
	$(BIN)/python benchmarks/throughput.py
	$(BIN)/python benchmarks/images.py

accuracy: $(VENV)/.installed
	$(BIN)/python benchmarks/accuracy.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
