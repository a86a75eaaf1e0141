# deapull — the verbs of the pipeline. `make help` lists them.
SHELL := /bin/bash
PY := .venv/bin/python
DEAPULL := .venv/bin/deapull
NP ?= 2
OUT ?= out
DATA ?= data
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
MPIRUN := mpirun -n $(NP)
#: the FEM's fidelity: empty (default) is the scene file as written, the data fidelity (its error against
#: the contact ladders: bench/reference/contact_reference.json); FIDELITY=preview is the quick look
FIDELITY ?=
FIDELITY_ARG := $(if $(FIDELITY),--fidelity $(FIDELITY))

.PHONY: help setup demo test test-data solve sweep fem-study fidelity stability bench control experiments \
	experiments-protocols report report-fields clean

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-16s %s\n", $$1, $$2}'

setup: ## install apt packages, the venv, torch (CPU) and the project (idempotent)
	@bash scripts/setup.sh

demo: setup ## main job on the default scene: mesh + FEM solve of coin_pull C3 (the data fidelity, one mesh over NP ranks), dataset and plot in out/demo
	$(MPIRUN) $(DEAPULL) solve --scene coin_pull --out $(OUT)/demo
	$(DEAPULL) plot $(OUT)/demo/C3.nc --out $(OUT)/demo/C3.png

test: setup ## run the test suite over $(NP) workers (pytest-xdist; serial and mpirun -n 2 checks)
	$(PY) -m pytest -q -n $(NP)

test-data: setup ## regenerate the tests' FEM fixture tests/data/sweep (mpirun -n 2, about a minute) and the control tests' models tests/data/models
	$(PY) tests/data/make_sweep.py
	$(PY) tests/data/make_models.py

solve: setup ## FEM solve of one setup: make solve SETUP=C5
	$(DEAPULL) solve --scene coin_pull --setup $(or $(SETUP),C3) $(FIDELITY_ARG) --out $(DATA)

#: PROTOCOLS=scene: the 8 ramps into $(DATA); push: the ramp in 80 ms (the MPC's full push), then held
#: 200 ms, into $(DATA)/push; excitation: ramp-hold-ramp, triangle, release and 3 random inputs for C1,
#: C3, C5, C7 into $(DATA)/excitation
PROTOCOLS ?= scene
SWEEP_OUT = $(if $(filter scene,$(PROTOCOLS)),$(DATA),$(DATA)/$(PROTOCOLS))
EXCITATION_SETUPS := --setups C1,C3,C5,C7
SWEEP_SETUPS = $(if $(filter excitation,$(PROTOCOLS)),$(EXCITATION_SETUPS))
sweep: setup ## the 8 setups under mpirun -n $(NP) (PROTOCOLS=scene|push|excitation) into $(DATA)/ (resumes)
	$(MPIRUN) $(DEAPULL) sweep --scene coin_pull $(FIDELITY_ARG) --protocols $(PROTOCOLS) $(SWEEP_SETUPS) --out $(SWEEP_OUT)

fem-study: setup ## the contact reference: two mesh ladders, the step halved, the data fidelity against their Richardson value (studies/contact_reference.toml; resumes; hours on 2 cores); writes bench/reference/contact_reference.json
	$(MPIRUN) $(DEAPULL) fem-study --study contact_reference --out $(OUT)/fem_study --publish bench/reference

fidelity: setup ## error against run time ladder on coin_pull C3 at FIDELITY (every rung refines or coarsens it); resumes
	$(MPIRUN) $(DEAPULL) fidelity --scene coin_pull --setup C3 $(FIDELITY_ARG) --out $(OUT)/fidelity

stability: setup ## stiff and extreme cases at FIDELITY (its header names it); resumes; writes bench/reference/stability.json
	$(MPIRUN) $(DEAPULL) stability $(FIDELITY_ARG) --out $(OUT)/stability
	cp $(OUT)/stability/stability.json bench/reference/stability.json

#: the presets' models (f_s,1, f_s,2 and f_a of surrogate, f_a of fem), committed: their weights depend
#: on the CPU that trains them; make control retrains one whose folder is missing
PLANTS := control/models
PRESET ?= surrogate
control: setup ## closed loop at a preset of control/presets: PRESET=surrogate (MPC, SAC, PD, heuristic on f_s,1 and f_s,2, Fig. 6; needs $(DATA)) or PRESET=fem (the MPC on fem:C1..C8 and the push-push-pull-back task on fem:C3)
ifeq ($(PRESET),fem)
	$(FA_MEM)
	$(DEAPULL) control --preset fem --data $(DATA) --out $(OUT)/control_fem
	cp $(OUT)/control_fem/summary.json bench/reference/control_fem.json
	$(DEAPULL) control --preset fem $(FEM_MULTI) --data $(DATA) --out $(OUT)/control_fem/multi
	cp $(OUT)/control_fem/multi/summary.json bench/reference/control_fem_multi.json
else
	$(FA_PUSH)
	@for s in 1 2; do test -f $(PLANTS)/fs$$s/model.json || $(DEAPULL) train --data $(DATA) --train C$$s \
		--val C$$((3 - s)) --model f-coulomb --epochs 300 --runs $(DATA)/push --out $(PLANTS)/fs$$s || exit 1; done
	$(DEAPULL) control --preset $(PRESET) --data $(DATA) --out $(OUT)/control
	cp $(OUT)/control/summary.json bench/reference/control_surrogate.json
endif

FEM_MULTI := --plant fem:C3 --setpoints-mm=-0.5,-1.0,-0.7 --episodes 1
FA_PUSH := @test -f $(PLANTS)/fa_push/model.json || ($(MAKE) --no-print-directory sweep PROTOCOLS=push && \
	$(DEAPULL) train --data $(DATA) --train C3,C4,C5,C6,C7 --val C8 --model f-coulomb --epochs 300 \
	--runs $(DATA)/push --out $(PLANTS)/fa_push)
FA_MEM := @test -f $(PLANTS)/fa_mem/model.json || $(DEAPULL) train --data $(DATA) --train C3,C4,C5,C6,C7 --val C8 \
	--model f-memory --epochs 300 --restarts 1 --out $(PLANTS)/fa_mem
MPC_PYTORCH := $(OUT)/mpc_pytorch
#: bench control's target (mm from the start), inside the reach of the f_a it trains; the paper's 1 mm
#: with a model that reaches it (BENCH_TARGET_MM=1.0)
BENCH_TARGET_MM ?= 0.8
FEM_PLANTS ?= C3
comma := ,
BENCH ?= fem
bench: setup ## speed, measured beside a baseline in the same run: BENCH=fem (C3 vs ABAQUS 130 s, the sweep), surrogate (1 s rollouts), control (MPC step vs mpc.pytorch and the paper's 1.2 s), control-fem (FEM_PLANTS), inference (LM update speed, and the calibration of what the inference tells), blas
ifeq ($(BENCH),fem)
	$(PY) bench/bench_fem.py --out $(OUT)/bench_fem --np $(NP)
	cp $(OUT)/bench_fem/bench_fem.json bench/reference/fem_speed.json
else ifeq ($(BENCH),surrogate)
	$(PY) bench/bench_surrogate.py --data $(DATA)
else ifeq ($(BENCH),control)
	@test -d $(MPC_PYTORCH)/mpc || .venv/bin/pip install --quiet --no-deps --target $(MPC_PYTORCH) mpc==0.0.6 \
		|| echo "mpc.pytorch could not be installed: the bench times ours only"
	$(PY) bench/bench_control.py --data $(DATA) --mpc-path $(MPC_PYTORCH) --out $(OUT)/bench_control \
		--target-mm $(BENCH_TARGET_MM)
else ifeq ($(BENCH),control-fem)
	$(FA_MEM)
	$(PY) bench/bench_control_fem.py --preset fem --plant $(subst $(comma),$(comma)fem:,fem:$(FEM_PLANTS)) \
		--data $(DATA) --out $(OUT)/bench_control_fem
else ifeq ($(BENCH),inference)
	$(FA_MEM)
	$(PY) bench/bench_inference.py --model $(PLANTS)/fa_mem
	$(FA_PUSH)
	$(PY) bench/bench_inference.py --model $(PLANTS)/fa_push --calibration 24 --noise 1e-6 \
		--out bench/reference/inference_calibration.json
else ifeq ($(BENCH),blas)
	$(PY) bench/bench_blas.py --out $(OUT)/bench_blas $(if $(BLAS_SOLVE),--solve)
else
	@echo "BENCH=$(BENCH): expected fem, surrogate, control, control-fem, inference or blas"; exit 2
endif

experiments: setup ## the paper's six sets (f-patch, NN, LSTM; 3 repeats of seeds) and the held-out friction pairs (needs $(DATA)); writes bench/reference/surrogate_*.json
	$(DEAPULL) experiments --data $(DATA) --out $(OUT)/experiments --models f-patch,nn,lstm --restarts f-patch=3 \
		--publish bench/reference
	$(DEAPULL) experiments-protocols --held-out-pairs --data $(DATA) --out $(OUT)/pairs --models f-patch-lag,f-coulomb,nn \
		--restarts f-patch-lag=5,f-coulomb=5 \
		--publish bench/reference

experiments-protocols: setup ## train on ramps + excitation, test held-out protocols and coins (needs $(DATA), $(DATA)/excitation; resumes)
	$(DEAPULL) experiments-protocols --data $(DATA) --excitation $(DATA)/excitation --out $(OUT)/protocols --ramp-results $(OUT)/experiments

report-fields: setup ## displacement fields of coin_pull C3 (XDMF) for the report's pictures, into $(OUT)/report_fields
	$(DEAPULL) solve --scene coin_pull --setup C3 $(FIDELITY_ARG) --out $(OUT)/report_fields --fields-every 10

REPORT_FAILED := $(OUT)/report/.failed-steps
report: setup ## the reproduction report $(OUT)/report/index.html + report.md; FULL=1 first runs the missing steps
	@mkdir -p $(OUT)/report; : > $(REPORT_FAILED)
ifneq ($(FULL),)
	@$(DEAPULL) report --outputs $(OUT) --data $(DATA) --missing-steps | while read -r args; do \
		echo "[report] outputs missing: make $$args"; \
		$(MAKE) --no-print-directory $$args || echo $$args >> $(REPORT_FAILED); \
	done
endif
	$(DEAPULL) report --out $(OUT)/report --outputs $(OUT) --data $(DATA)
	@if [ -s $(REPORT_FAILED) ]; then echo "[report] these steps failed: $$(cat $(REPORT_FAILED) | tr '\n' ' ')"; \
		rm -f $(REPORT_FAILED); exit 1; fi; rm -f $(REPORT_FAILED)

clean: ## remove generated output (keeps .venv and data/)
	rm -rf $(OUT) .pytest_cache
