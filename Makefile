# deapull — the verbs of the pipeline. `make help` lists them.
SHELL := /bin/bash
PY := .venv/bin/python
DEAPULL := .venv/bin/deapull
NP ?= 2
OUT ?= out
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
MPIRUN := mpirun -n $(NP)

.PHONY: help setup demo test mesh clean

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-16s %s\n", $$1, $$2}'

setup: ## install apt packages, the venv, torch (CPU) and the project (idempotent)
	@bash scripts/setup.sh

demo: setup ## the main job on the default scene (coin_pull, setup C3)
	$(DEAPULL) mesh --scene coin_pull --out $(OUT)/demo/mesh

test: setup ## run the test suite (serial and mpirun -n 2 checks)
	$(PY) -m pytest -q

mesh: setup ## mesh the default scene into $(OUT)/mesh
	$(DEAPULL) mesh --scene coin_pull --out $(OUT)/mesh

clean: ## remove generated output (keeps .venv)
	rm -rf $(OUT) .pytest_cache
