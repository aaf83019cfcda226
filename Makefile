# The two commands a new machine needs: `make demo` and `make test`. Each does the whole set-up.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
DEMO   ?= demo-out

.PHONY: setup demo test lint bench clean

$(STAMP): pyproject.toml tools/setup.sh
	bash tools/setup.sh $(VENV)
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/gonio simulate "cook-torrance:d=beckmann,m=0.3,metal=gold,rho_d=0.1" \
		--grid iso:step=10 --out $(DEMO) --seed 1
	$(VENV)/bin/gonio plan --grid iso:step=5

test: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider

lint: $(STAMP)
	$(VENV)/bin/ruff check gonio drivers sim tests tools

bench: $(STAMP)
	$(PY) tools/bench_materials.py
	$(PY) tools/bench_plan.py
	$(PY) tools/bench_runner.py

clean:
	rm -rf $(VENV) $(DEMO) build *.egg-info
