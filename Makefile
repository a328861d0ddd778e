# Two entry points for newcomers (see README): `make demo` and `make test`.
VENV ?= .venv
BIN = $(VENV)/bin

.PHONY: install demo test bench lint clean

install: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml backends/pyproject.toml policies/pyproject.toml scripts/install.sh
	VENV=$(VENV) scripts/install.sh

demo: install
	$(BIN)/l2calib demo --force

test: install
	$(BIN)/python -m pytest -q --durations=15

bench: install
	$(BIN)/python -m benchmarks

lint: install
	$(BIN)/python -m ruff check l2calib backends policies tests benchmarks
	$(BIN)/python -m ruff format --check l2calib backends policies tests benchmarks

clean:
	rm -rf $(VENV) .pytest_cache
