# The two commands a new machine needs: `make demo` and `make test`. Each does the set-up it needs:
# `make demo` the runtime dependencies only, `make test` also the development extras and chromium.
VENV    ?= .venv
PY      := $(VENV)/bin/python
RUNTIME := $(VENV)/.runtime-stamp
DEV     := $(VENV)/.dev-stamp
DEMO    ?= demo-out

.PHONY: setup demo test lint bench clean

$(RUNTIME): pyproject.toml tools/setup.sh
	@echo "make: installing gonio and its runtime dependencies into $(VENV)"
	@bash tools/setup.sh $(VENV) runtime
	@touch $@

# The development set-up includes the runtime one.
$(DEV): pyproject.toml tools/setup.sh
	@echo "make: installing gonio, its runtime dependencies and the development extras into $(VENV)"
	@bash tools/setup.sh $(VENV) dev
	@touch $@ $(RUNTIME)

setup: $(DEV)

demo: $(RUNTIME)
	$(VENV)/bin/gonio simulate "cook-torrance:d=beckmann,m=0.3,metal=gold,rho_d=0.1" \
		--grid iso:step=10 --out $(DEMO) --seed 1
	$(VENV)/bin/gonio plot $(DEMO) --kind polar --out $(DEMO)/polar.png --force

# On every core (pytest-xdist): each worker is handed the next test or two as it finishes, in the order
# tests/conftest.py sets (the slow tests first, the longest first, so that none is left to run alone at
# the end; without --maxschedchunk one worker is handed every slow test at the start).
# Byte-code caches are written even where PYTHONDONTWRITEBYTECODE is set: tools/setup.sh installs with
# --no-compile, so otherwise every worker and every `gonio` subprocess of the tests compiles numpy,
# scipy, pydantic... from source again (1-2 s of CPU per command), and pytest rewrites the asserts
# of ~450 plugin modules in every worker.
test: $(DEV)
	env -u PYTHONDONTWRITEBYTECODE $(PY) -m pytest -q -p no:cacheprovider -n auto --dist load --maxschedchunk 2 --durations=15

lint: $(DEV)
	$(VENV)/bin/ruff check gonio drivers sim tests tools examples

bench: $(DEV)
	$(PY) tools/bench_materials.py
	$(PY) tools/bench_plan.py
	$(PY) tools/bench_runner.py

clean:
	rm -rf $(VENV) $(DEMO) build *.egg-info
