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
	$(BB) render wood --views fibonacci:8 --resolution 128 --out out/demo/wood
	$(BB) inspect out/demo/wood
	@if [ -d $(SHARED)/captures/card_blue ]; then \
	  $(BB) inspect $(SHARED)/captures/card_blue --resolution 128 && \
	  $(BB) render leather --capture $(SHARED)/captures/card_blue --resolution 128 --out out/demo/leather_at_card_blue; \
	else echo "demo: $(SHARED) not found, skipping the real-capture part"; fi
	@echo "demo: outputs in $(CURDIR)/out/demo (preview_*.png are sRGB previews, view_*.exr linear radiance)"

test: setup
	$(PY) -m pytest -q tests bayes_brdf --doctest-modules

docs: setup
	$(VENV)/bin/mkdocs build --strict -d site

bench: setup
	$(PY) benchmarks/bench_render.py

clean:
	rm -rf out site build dist *.egg-info
