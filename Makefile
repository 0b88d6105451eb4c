# Two commands do all set-up on a fresh machine: `make run` and `make test`.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test fuzz docs lint stress soak bench mutants clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test,dev,robots]"  # robots: the real URDF robots the tests load
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/warpimpulse simulate --scene tree127 --duration 10 --fps 30  # -> out/tree127.usdc

# The suite on the default schedule (fused on a CPU), then on the parallel schedule, what a GPU runs (the tests
# of the fused schedule itself, and those that step no simulator, such as the CUDA compilation, are skipped there).
test: $(STAMP)
	$(PY) -m pytest -q -m "not slow" tests
	$(PY) -m pytest -q -m "not slow" tests --schedule parallel

# The property and fuzz tests with fresh random cases (make test replays a fixed set): explores, may find new failures.
fuzz: $(STAMP)
	$(PY) -m pytest -q tests/test_properties.py --hypothesis-profile fuzz --hypothesis-show-statistics
	WARPIMPULSE_FUZZ_EXAMPLES=500 $(PY) -m pytest -q tests/test_fuzz_usd.py --hypothesis-profile fuzz

# Break the engine on purpose, one curated mutation at a time (tests/mutants/mutations.toml), and list the
# mutations the fast suite does not notice. Minutes per mutation; not part of `make test`.
mutants: $(STAMP)
	$(PY) tests/mutants/run.py

# Documents generated from the code: the capability table (tests/test_capabilities.py keeps it current).
docs: $(STAMP)
	$(PY) -c "from warpimpulse.capabilities import markdown; print(markdown(), end='')" > docs/capabilities.md

lint: $(STAMP)
	$(VENV)/bin/ruff check . && $(VENV)/bin/ruff format --check .

stress: $(STAMP)
	$(VENV)/bin/warpimpulse stress

# Long runs with a checkpoint and resume every 10,000 steps: joint drift, energy drift, memory (flat or exit 1).
soak: $(STAMP)
	$(PY) benchmarks/soak.py --json benchmarks/results/soak.json

# Every URDF of example-robot-data (the [robots] extra) loaded, or refused with one line naming the element, and
# run 10 s at h = 1 ms under gravity, contacts off, two robots at a time: benchmarks/results/robots.{json,md}.
# Then every MJCF of gymnasium and dm_control's suite at orders 2 and 4: benchmarks/results/mjcf_robots.{json,md}.
robots: $(STAMP)
	$(PY) -m pip install -q -e ".[robots]"
	$(PY) benchmarks/robots.py --processes 2
	$(PY) benchmarks/mjcf_robots.py > /dev/null

# The paper's tables, run time against error and scaling (apart, so each can be re-run alone), then the
# plots, RESULTS.md and docs/results.md's results block from the three JSON files; scene_kinds.py also writes
# README.md's summary of its table.
RESULTS := benchmarks/results
bench: $(STAMP)
	$(PY) -m pip install -q -e ".[bench]"
	$(PY) benchmarks/paper_tables.py
	$(PY) benchmarks/skips.py
	$(PY) benchmarks/step_breakdown.py --readme docs/results.md > /dev/null
	$(PY) benchmarks/worlds.py --readme docs/guide.md > /dev/null
	$(PY) benchmarks/run_vs_error.py --json $(RESULTS)/run_vs_error.json > /dev/null
	$(PY) benchmarks/scaling.py --json $(RESULTS)/scaling.json > /dev/null
	$(PY) benchmarks/orders.py > /dev/null  # orders in time: orders.json, docs/time-order.md, README's orders block
	$(PY) benchmarks/scene_kinds.py > /dev/null  # kinds of scene from MJCF: scene_kinds.json, plots, README block
	$(PY) benchmarks/split_forces.py > /dev/null  # kicks against the coupled prediction: docs/mechanisms.md
	$(PY) -m warpimpulse.bench.report --from-json $(RESULTS)/paper_tables.json $(RESULTS)/run_vs_error.json $(RESULTS)/scaling.json \
		--plots $(RESULTS) --report $(RESULTS)/RESULTS.md --readme docs/results.md

clean:
	rm -rf $(VENV) build *.egg-info out/tree127.usdc
