# Two entry points (README): `make demo` and `make test`. Both install first.
VENV := .venv
POEVP := $(VENV)/bin/poevp
PYTEST := $(VENV)/bin/python -m pytest

.PHONY: install demo test bench clean

install:
	bash scripts/setup.sh

demo: install
	$(POEVP) render scenes/night_road --out out/night_road

test: install
	$(PYTEST) -q -ra tests

bench: install
	$(VENV)/bin/python -m benchmarks

clean:
	rm -rf out build *.egg-info
