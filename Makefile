# The two commands (see README): `make demo` and `make test`. Both set up .venv on first use.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.warpface-installed

.PHONY: demo test test-slow lint bench setup clean

$(STAMP): pyproject.toml scripts/setup.sh
	VENV=$(VENV) bash scripts/setup.sh
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/warpface demo

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# Two workers, one test file each at a time (module fixtures stay in one process). `make test` is the suite
# without the end-to-end runs over 20 s (marked `slow`); `make test-slow` runs those, and CI runs both.
test: $(STAMP) lint
	$(PY) -m pytest -q -n 2 --dist loadfile --durations=15 -m "not slow"

test-slow: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile -m slow

bench: $(STAMP)
	$(PY) -m benchmarks.expression

clean:
	rm -rf $(VENV) demo build dist *.egg-info
