# bayes-brdf: `make demo` and `make test` each install everything first (scripts/setup.sh).
VENV ?= .venv
PY := $(VENV)/bin/python
BB := $(VENV)/bin/bayes-brdf
SHARED ?= ../shared/data
export DRJIT_LIBLLVM_PATH ?= /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1

.PHONY: setup demo test docs bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(BB) demo --out out/demo/story
	@if [ -d $(SHARED)/captures/card_blue ]; then \
	  $(BB) recommend $(SHARED)/captures/card_blue --views 0,2,4,6,8 --resolution 32 --steps 1500 --k 2 --out out/demo/card_blue; \
	else echo "demo: $(SHARED) not found, skipping the real-capture part"; fi
	@echo "demo: open $(CURDIR)/out/demo/story/report.html in a browser"

test: setup
	$(PY) -m pytest -q tests bayes_brdf --doctest-modules

docs: setup
	$(VENV)/bin/mkdocs build --strict -d site

bench: setup
	$(PY) benchmarks/bench_render.py

clean:
	rm -rf out site build dist *.egg-info
