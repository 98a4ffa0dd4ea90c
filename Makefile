# Two entry points (README): `make demo` and `make test`. Both install first.
VENV := .venv
POEVP := $(VENV)/bin/poevp
PYTEST := $(VENV)/bin/python -m pytest

.PHONY: install demo test bench docs clean

install:
	bash scripts/setup.sh

demo: install
	$(POEVP) render scenes/night_road --out out/night_road

# Two workers (pytest-xdist): CI's two cores; tests/conftest.py keeps each module on one worker
# and has each worker render on one thread.
test: install
	$(PYTEST) -q -ra -n 2 --dist loadgroup tests

# Refreshes the committed results (benchmarks/results/, the site's Results pages) on purpose:
# a benchmark run by hand writes into out/benchmarks/ unless given --results.
bench: install
	$(VENV)/bin/python -m benchmarks --results

# The documentation site (docs/, mkdocs.yml) into site/; warnings are errors.
docs: install
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

clean:
	rm -rf out build site *.egg-info
