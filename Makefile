PY ?= python

DEMO ?= runs/demo
# Three tenths of the paper's budget, so that the demo takes a few minutes on 2 cores: with the
# default's 5 passes over each rollout, 15,000 steps train in about the time 10,000 took with 10.
DEMO_STEPS ?= 15000
# The default configuration (zoo/ippo.yml, the best measured); DEMO_CONFIG=ippo_paper trains the
# paper-faithful one.
DEMO_CONFIG ?= ippo

.PHONY: setup test test-slow lint format type bench demo

setup:
	$(PY) -m pip install torch==2.13.0
	$(PY) -m pip install -e ".[tests,dev]"

test:
	$(PY) -m pytest -n 2 -q

test-slow:
	$(PY) -m pytest -m slow -q

lint:
	ruff check sb3_pm tests examples benchmarks

format:
	ruff format sb3_pm tests examples benchmarks
	ruff check --fix sb3_pm tests examples benchmarks

type:
	mypy sb3_pm

bench:
	$(PY) benchmarks/env_speed.py
	$(PY) benchmarks/eval_speed.py

# The README's main job: train a team briefly on paper-50, then evaluate it next to the baselines.
demo:
	sb3-pm train --config $(DEMO_CONFIG) --env paper-50 --seed 0 --timesteps $(DEMO_STEPS) --out $(DEMO) --overwrite
	sb3-pm compare --policies $(DEMO) random local_greedy sit_on_nodes grazing territory_patrol --graphs paper-50 --seeds 0 --episodes 5 \
		--out $(DEMO)/report --overwrite
