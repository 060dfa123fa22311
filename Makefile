PY ?= python
SHARED ?= ../shared

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
