# The two commands that do everything on a fresh machine:
#   make render   renders sample_blends/floating_boxes.blend to out/ (EXR + PNG; creates .venv on first use)
#   make test     runs the whole test suite
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: render test bench clean node

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# The sample .blend through the installed `lazyvis` command, as `blender -b ... -E LAZYVIS -f 1` would.
render: $(STAMP)
	$(VENV)/bin/lazyvis render sample_blends/floating_boxes.blend -f 1 -o out/floating_boxes.exr --png out/floating_boxes.png

test: $(STAMP) node
	$(PY) -m pytest -q

# The Flamenco job type's tests compile it under Node: Debian's nodejs where the machine has none.
node:
	@command -v node >/dev/null 2>&1 || command -v nodejs >/dev/null 2>&1 || \
		(apt-get update -qq && apt-get install -y -qq nodejs >/dev/null)

# LazyVis against Cycles at equal error on every sample (issue 15; about an hour, references cached).
bench: $(STAMP)
	$(PY) bench/bench_vs_cycles.py --json vs_cycles.json

clean:
	rm -rf out build dist
