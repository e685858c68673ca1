# Two set-up commands for a fresh machine: `make demo` and `make test`.
# Both create ./.venv and install fedtrack into it (editable) on first use.
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -e '.[dev]'
	touch $(STAMP)

.PHONY: install demo test reproduce bench
install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/fedtrack demo

test: $(STAMP)
	$(VENV)/bin/python -m pytest -q -n 2 --dist loadfile

bench: $(STAMP)
	$(VENV)/bin/fedtrack bench
