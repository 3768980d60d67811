# bayes-brdf: `make demo` and `make test` each install everything first (scripts/setup.sh).
VENV ?= .venv
PY := $(VENV)/bin/python
BB := $(VENV)/bin/bayes-brdf
SHARED ?= ../shared/data
# `make demo DEMO_FLAGS=--overwrite`: start over in out/demo/story when it holds an older demo's run
DEMO_FLAGS ?=
export DRJIT_LIBLLVM_PATH ?= /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1

.PHONY: setup demo test docs bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	@if [ -d $(SHARED)/captures/card_blue ]; then \
	  $(BB) demo --out out/demo/story --capture $(SHARED)/captures/card_blue \
	    --mesh $(SHARED)/psdr_assets/bunny_low.obj --mesh-up y $(DEMO_FLAGS); \
	else echo "demo: $(SHARED) not found: the report leaves out the real-capture section, and shows the bowl"; \
	  $(BB) demo --out out/demo/story $(DEMO_FLAGS); fi

test: setup
	$(PY) -m pytest -q tests bayes_brdf --doctest-modules

docs: setup
	$(VENV)/bin/mkdocs build --strict -d site

bench: setup
	$(PY) benchmarks/bench_render.py

clean:
	rm -rf out site build dist *.egg-info
