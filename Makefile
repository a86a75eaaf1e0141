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

.PHONY: help setup demo test mesh solve sweep excitation push-ramps bench-fem bench-blas bench-control-fem bench-inference control-fem control-fem-seeds control-fem-infer fem-study bench-surrogate fidelity stability control experiments experiments-protocols \
	report report-fields clean

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-16s %s\n", $$1, $$2}'

setup: ## install apt packages, the venv, torch (CPU) and the project (idempotent)
	@bash scripts/setup.sh

demo: setup ## main job on the default scene: mesh + FEM solve of coin_pull C3 (the data fidelity), dataset and plot in out/demo
	$(DEAPULL) solve --scene coin_pull --out $(OUT)/demo
	$(DEAPULL) plot $(OUT)/demo/C3.nc --out $(OUT)/demo/C3.png

test: setup ## run the test suite (serial and mpirun -n 2 checks)
	$(PY) -m pytest -q

test-data: setup ## regenerate the surrogate tests' FEM fixture tests/data/sweep (mpirun -n 2, about a minute)
	$(PY) tests/data/make_sweep.py

mesh: setup ## mesh the default scene into $(OUT)/mesh
	$(DEAPULL) mesh --scene coin_pull --out $(OUT)/mesh

solve: setup ## FEM solve of one setup: make solve SETUP=C5
	$(DEAPULL) solve --scene coin_pull --setup $(or $(SETUP),C3) $(FIDELITY_ARG) --out $(DATA)

sweep: setup ## the 8 setups under mpirun -n $(NP) into $(DATA)/ (resumes if interrupted)
	$(MPIRUN) $(DEAPULL) sweep --scene coin_pull $(FIDELITY_ARG) --out $(DATA)

push-ramps: setup ## the ramp in 80 ms (the MPC's full push, 5 V per 1 ms step), then held 200 ms, for C1..C8 into $(DATA)/push (resumes; 3-5 min a setup; the rim band and table that a fast push needs)
	$(MPIRUN) $(DEAPULL) sweep --scene coin_pull $(FIDELITY_ARG) --protocols push --out $(DATA)/push

excitation: setup ## ramp-hold-ramp, triangle, release, 3 random inputs for C1,C3,C5,C7 into $(DATA)/excitation (resumes)
	$(MPIRUN) $(DEAPULL) sweep --scene coin_pull $(FIDELITY_ARG) --setups C1,C3,C5,C7 --protocols excitation \
		--out $(DATA)/excitation

bench-fem: setup ## FEM wall time, travel error and x(t) MAE vs the committed contact-ladder reference (its bound and what it leaves out), Newton its, 8-setup sweep; beside ABAQUS 130 s
	$(PY) bench/bench_fem.py --out $(OUT)/bench_fem --np $(NP)

bench-blas: setup ## the resolved Jacobian's LU (MUMPS, UMFPACK) with the system BLAS (OpenBLAS) vs the reference BLAS, same run; BLAS_SOLVE=1 adds the whole C3 ramp under both
	$(PY) bench/bench_blas.py --out $(OUT)/bench_blas $(if $(BLAS_SOLVE),--solve)

fem-study: setup ## the contact reference: two mesh ladders, the step halved, the data fidelity against their Richardson value (studies/contact_reference.toml; resumes; hours on 2 cores); writes bench/reference/contact_reference.json
	$(MPIRUN) $(DEAPULL) fem-study --study contact_reference --out $(OUT)/fem_study --publish bench/reference

fidelity: setup ## error against run time ladder on coin_pull C3 at FIDELITY (every rung refines or coarsens it); resumes
	$(MPIRUN) $(DEAPULL) fidelity --scene coin_pull --setup C3 $(FIDELITY_ARG) --out $(OUT)/fidelity

stability: setup ## stiff and extreme cases at FIDELITY; resumes
	$(MPIRUN) $(DEAPULL) stability $(FIDELITY_ARG) --out $(OUT)/stability

bench-surrogate: setup ## 1 s rollout time of each surrogate model (needs $(DATA) from make sweep)
	$(PY) bench/bench_surrogate.py --data $(DATA)

MPC_PYTORCH := $(OUT)/mpc_pytorch
#: the bench's target (mm from the start): 0.8 mm, inside the reach of the f_a the bench trains on the
#: resolved data (C1's coin: 0.842 mm at 400 V, eighteenth session; 0.85 mm, inside the reach on the
#: one-point data with the table, was refused there with exit 2); the paper's 1 mm is refused too (exit
#: 2, with the reach); BENCH_TARGET_MM=1.0 with a model that reaches it
BENCH_TARGET_MM ?= 0.8
bench-control: setup ## ms per MPC step: our box-iLQR vs mpc.pytorch (installed apart, in $(OUT)/mpc_pytorch), beside the paper's 1.2 s
	@test -d $(MPC_PYTORCH)/mpc || .venv/bin/pip install --quiet --no-deps --target $(MPC_PYTORCH) mpc==0.0.6 \
		|| echo "mpc.pytorch could not be installed: the bench times ours only"
	$(PY) bench/bench_control.py --data $(DATA) --mpc-path $(MPC_PYTORCH) --out $(OUT)/bench_control \
		--target-mm $(BENCH_TARGET_MM)

FEM_PLANTS ?= C3
comma := ,
bench-control-fem: setup ## one episode of make control-fem's MPC on the FEM plant per setup in FEM_PLANTS: ms per FEM step and per plan, wall time per episode (needs $(DATA))
	$(FA_MEM)
	$(PY) bench/bench_control_fem.py $(FEM_CONTROL) --plant $(subst $(comma),$(comma)fem:,fem:$(FEM_PLANTS)) \
		--data $(DATA) --out $(OUT)/bench_control_fem

MODELS ?= $(OUT)/models
NOISE ?= 0,1e-5,1e-4,1e-3
#: the MPC's arrival on the surrogates: at 5 V per step the coin moves ~40 um a step near 390 V and
#: coasts ~20 um after the push, and under noise the MPC plans from f_a's velocity (8-20 % below the
#: plant's), so it overshoots; a 0.1 mm taper (without the reach gate, which the prior's median fires at
#: C1's -1 mm) costs 1-4 iterations. Measured (eighteenth session, docs/control.md): settled at 1e-5
#: C1 2/10 -> 10/10, C2 10/10; at 1e-4 C1 2/10 -> 4/10, C2 7/10 -> 9/10; noise 0 10/10 at 81 / 82 (was 80).
#: A stand-off of 2 stds (twenty-second session): under noise the MPC stops short, lets the observations
#: average its estimate down, then creeps in. At 1e-4 it settles 59 of 60 episodes (45 of 60 without) at
#: medians of 255-856 iterations; no controller settles 10/10 within ~100 there (the information bound,
#: docs/control.md "What noise allows"). Noise 0 and 1e-5: 10/10 at 81-88, as without it
MPC_ARRIVAL ?= --mpc-approach-mm 0.1 --mpc-no-reach-gate --mpc-standoff 2
#: make control's f_a (fa_push): f-coulomb on the C3..C7 ramps and on their 80 ms pushes ($(DATA)/push, make
#: push-ramps), the MPC's own rate: under that push the ramp-only f_a ends 10 % short of f_s,1 / f_s,2, this one
#: +0.1-0.3 % (twenty-first session, docs/control.md: at 1e-4, 39 of 60 episodes settled against 31 of 60)
control: setup ## closed loop: MPC, SAC, PD, heuristic on f_s,1 and f_s,2, 10 episodes per noise in NOISE (needs $(DATA); runs make push-ramps first when f_a is missing, ~25 min)
	@for s in 1 2; do test -f $(MODELS)/fs$$s/model.json || $(DEAPULL) train --data $(DATA) --train C$$s \
		--val C$$((3 - s)) --model f-coulomb --epochs 300 --out $(MODELS)/fs$$s || exit 1; done
	@test -f $(MODELS)/fa_push/model.json || $(MAKE) --no-print-directory push-ramps
	@test -f $(MODELS)/fa_push/model.json || $(DEAPULL) train --data $(DATA) --train C3,C4,C5,C6,C7 --val C8 \
		--model f-coulomb --epochs 300 --runs $(DATA)/push --out $(MODELS)/fa_push
	$(DEAPULL) control --policy mpc,sac,pd,heur --plant surrogate:C1,surrogate:C2 --episodes 10 --noise $(NOISE) \
		--phi-prior coins --data $(DATA) --plant-model '$(MODELS)/fs{n}' --mpc-model $(MODELS)/fa_push --sac-dir '$(MODELS)/sac{n}' \
		$(MPC_ARRIVAL) --out $(OUT)/control

# issue 24's FEM setting (docs/control.md, ninth session): the sweep's 0.4 V per step (a slow push
# carries the heavy coins to the target), tapered within 0.1 mm of the target down to 0.1 V per step;
# the f-memory f_a (it models the tip's dead band, so a coin parked short restarts; it plans at the
# coin prior's median: at noise 1e-4 the data identify no field of φ, docs/control.md), a stand-off of 2 stds (the estimate averages down before
# the last push; it gives way at the edge of the reach) and the bias filter's innovation check over 25
# steps (the estimate follows the release of a pull-back). A plant whose ramp does not take its coin
# to the target (on the resolved contact: C5, C6, C8 at -1 mm) is a row "unreachable" in the table.
FEM_COMMON := --policy mpc --episodes 1 --noise 1e-4 --phi-prior coins --mpc-max-rate 0.4 --mpc-approach-mm 0.1 \
	--mpc-creep 0.1 --unreachable report $(FIDELITY_ARG)
FEM_ALL := fem:C1,fem:C2,fem:C3,fem:C4,fem:C5,fem:C6,fem:C7,fem:C8
FEM_MULTI := --plant fem:C3 --setpoints-mm=-0.5,-1.0,-0.7
FEM_CONTROL := $(FEM_COMMON) --max-steps 4000 --mpc-model $(MODELS)/fa_mem --mpc-no-infer --mpc-standoff 2 \
	--mpc-innovation-window 25
FA_MEM := @test -f $(MODELS)/fa_mem/model.json || $(DEAPULL) train --data $(DATA) --train C3,C4,C5,C6,C7 --val C8 \
	--model f-memory --epochs 300 --restarts 1 --out $(MODELS)/fa_mem
bench-inference: setup ## ms per online-inference update of the f-memory f_a: compiled vs torch, same run (needs $(DATA))
	$(FA_MEM)
	$(PY) bench/bench_inference.py --model $(MODELS)/fa_mem

control-fem: setup ## the offset-free MPC on the FEM plants fem:C1..C8 (noise 1e-4) and the push-push-pull-back task on fem:C3 (resolved: ~1.5 h on one core, 7-25 min an episode)
	$(FA_MEM)
	$(DEAPULL) control $(FEM_CONTROL) --plant $(FEM_ALL) --out $(OUT)/control_fem
	$(DEAPULL) control $(FEM_CONTROL) $(FEM_MULTI) --out $(OUT)/control_fem/multi

# issue 24's three-seed FEM goal: fem:C1 and fem:C3, seeds 0-2 (episode k is seed k), control-fem's setting
control-fem-seeds: setup ## fem:C1 and fem:C3, three seeds each, control-fem's setting (resolved: ~1.5 h on one core, 7-15 min an episode)
	$(FA_MEM)
	$(DEAPULL) control $(FEM_CONTROL) --episodes 3 --plant fem:C1,fem:C3 --out $(OUT)/control_fem_seeds

# the fourth session's setting, with online inference of φ: the f-coulomb f_a (trained on the C3..C7
# ramps), no stand-off, no innovation check, 3,000 steps (docs/control.md: 4 of 6 seeds settled)
FEM_CONTROL_INFER := $(FEM_COMMON) --max-steps 3000 --mpc-model $(MODELS)/fa
control-fem-infer: setup ## control-fem's tasks with the f-coulomb f_a and online inference of φ (the fourth session's setting; resolved: ~1 h)
	@test -f $(MODELS)/fa/model.json || $(DEAPULL) train --data $(DATA) --train C3,C4,C5,C6,C7 --val C8 \
		--model f-coulomb --epochs 300 --out $(MODELS)/fa
	$(DEAPULL) control $(FEM_CONTROL_INFER) --plant $(FEM_ALL) --out $(OUT)/control_fem_infer
	$(DEAPULL) control $(FEM_CONTROL_INFER) $(FEM_MULTI) --out $(OUT)/control_fem_infer/multi

experiments: setup ## the paper's six sliding sets for every model, best of 5 seeds on each validation setup (needs $(DATA))
	$(DEAPULL) experiments --data $(DATA) --out $(OUT)/experiments

experiments-protocols: setup ## train on ramps + excitation, test held-out protocols and coins (needs $(DATA), $(DATA)/excitation; resumes)
	$(DEAPULL) experiments-protocols --data $(DATA) --excitation $(DATA)/excitation --out $(OUT)/protocols --ramp-results $(OUT)/experiments

report-fields: setup ## displacement fields of coin_pull C3 (XDMF) for the report's pictures, into $(OUT)/report_fields
	$(DEAPULL) solve --scene coin_pull --setup C3 $(FIDELITY_ARG) --out $(OUT)/report_fields --fields-every 10

REPORT_FAILED := $(OUT)/report/.failed-steps
report: setup ## the reproduction report $(OUT)/report/index.html + report.md; FULL=1 first runs the missing steps
	@mkdir -p $(OUT)/report; : > $(REPORT_FAILED)
ifneq ($(FULL),)
	@for step in $$($(DEAPULL) report --outputs $(OUT) --data $(DATA) --missing-steps); do \
		echo "[report] outputs missing: make $$step"; \
		$(MAKE) --no-print-directory $$step || echo $$step >> $(REPORT_FAILED); \
	done
endif
	$(DEAPULL) report --out $(OUT)/report --outputs $(OUT) --data $(DATA)
	@if [ -s $(REPORT_FAILED) ]; then echo "[report] these steps failed: $$(cat $(REPORT_FAILED) | tr '\n' ' ')"; \
		rm -f $(REPORT_FAILED); exit 1; fi; rm -f $(REPORT_FAILED)

clean: ## remove generated output (keeps .venv and data/)
	rm -rf $(OUT) .pytest_cache
