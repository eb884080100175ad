# ngcontact: every target bootstraps .venv on a fresh machine.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo demo-figure test test-install test-slow venv clean help

$(STAMP): pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

## help: list the targets with their descriptions
help:
	@awk '/^## [a-z-]+:/ { b = 1; sub(/^## /, ""); print "  " $$0; next } \
	      b && /^##/ { sub(/^## */, ""); print "      " $$0; next } { b = 0 }' $(MAKEFILE_LIST)

## venv: create .venv and install the package (every target does this first)
venv: $(STAMP)

## demo: test 1 of [CAMWA21], FEM P1 and P2 on T0..T3 -> results/runs/demo/ (not tracked)
demo: $(STAMP)
	$(PY) -m ngcontact demo --out results/runs/demo

## demo-figure: rerun the demo and copy its overview to results/demo/convergence.png (the README's figure)
demo-figure: demo
	cp results/runs/demo/convergence.png results/demo/convergence.png

## test: fast test suite, including the wheel-install test (a few minutes on 2 cores, venv bootstrap included)
test: $(STAMP)
	$(PY) -m pytest -q tests ngcontact

## test-install: only the wheel-install test: build the wheel, install it into a fresh venv, run it elsewhere
test-install: $(STAMP)
	$(PY) -m pytest -q tests/test_install.py

## reference-histories: rerun the short reference runs of tests/reference_runs.py and rewrite
## tests/data/reference_histories.json (only when a change of the numbers is intended)
.PHONY: reference-histories
reference-histories: $(STAMP)
	$(PY) -m tests.reference_runs

## test-slow: also the long convergence studies
test-slow: $(STAMP)
	$(PY) -m pytest -q -m "" tests ngcontact

## clean: remove the CLI's default run directories (results/runs), pytest's cache and build/ of pip install .
clean:
	rm -rf results/runs .pytest_cache build

# Study runs are written to NAME.part and renamed to NAME when they finish: a killed run leaves
# NAME.part (replaced by the next attempt) and never a directory that make would take as done.
## fem-study: [CAMWA21] tests 1 and 2, FEM P1..P4 on T0..T4 (nested start; cold start for
## the Newton counts of the paper) -> results/fem/TABLES.md.  `make -j2 fem-study` runs in parallel.
FEM_RUNS := $(foreach t,test1 test2,$(foreach p,1 2 3 4,results/fem/$(t)-p$(p)-nested)) \
            $(foreach p,1 2 3 4,results/fem/test1-p$(p)-cold)
.PHONY: fem-study
fem-study: $(FEM_RUNS)
	$(PY) -m ngcontact table $(FEM_RUNS) --out results/fem/TABLES.md
	$(PY) -m ngcontact plot $(filter results/fem/test1-%-nested,$(FEM_RUNS)) --out results/fem/test1.png --title "test1 [CAMWA21], FEM"
	$(PY) -m ngcontact plot $(filter results/fem/test2-%-nested,$(FEM_RUNS)) --out results/fem/test2.png --title "test2 [CAMWA21], FEM"

results/fem/%: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact run $(word 1,$(subst -, ,$*)) --order $(subst p,,$(word 2,$(subst -, ,$*))) \
	  --levels 5 --start $(word 3,$(subst -, ,$*)) --no-vtk -q --out $@.part && rm -rf $@ && mv $@.part $@

## constraints-study: contact nodes whose Lagrange basis functions have no negative integral (--constraints
## nodal, the default) against the equispaced lattice of [CAMWA21] (--constraints equispaced), P4: tests 1 and 2
## FEM on T0..T4, test 1 HHO and SIPG on T0..T3, test 1 FEM --estimate on T0..T3; with the weights and
## Lebesgue constants of the node sets, p = 1..6; --constraints bernstein: test 1 P2-P4 (nested T0..T4, cold
## start T0..T3 next to nodal), test 2 P4, test 1 P4 --estimate -> results/fem/CONSTRAINTS.md.  `make -j2`: two at a time.
CONS_RUNS := $(foreach c,nodal equispaced,$(foreach t,test1 test2,results/constraints/runs/$(t)-fem-p4-$(c)) \
               $(foreach d,hho sipg,results/constraints/runs/test1-$(d)-p4-$(c)) results/constraints/runs/test1-fem-p4-$(c)-estimate) \
             $(foreach p,2 3 4,results/constraints/runs/test1-fem-p$(p)-bernstein \
               $(foreach c,nodal bernstein,results/constraints/runs/test1-fem-p$(p)-$(c)-cold)) \
             results/constraints/runs/test2-fem-p4-bernstein results/constraints/runs/test1-fem-p4-bernstein-estimate
.PHONY: constraints-study
constraints-study: $(CONS_RUNS)
	$(PY) -m ngcontact.studies.constraints results/fem/CONSTRAINTS.md $(CONS_RUNS)

# words of a run name SCENE-DISC-pP-CONSTRAINTS[-estimate|-cold]; nested FEM without estimators on 5 levels, the others on 4
cons_word = $(word $(1),$(subst -, ,$(2)))
results/constraints/runs/%: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact run $(call cons_word,1,$*) --disc $(call cons_word,2,$*) \
	  --order $(subst p,,$(call cons_word,3,$*)) --constraints $(call cons_word,4,$*) \
	  $(if $(filter estimate,$(call cons_word,5,$*)),--estimate) $(if $(filter cold,$(call cons_word,5,$*)),--start cold) \
	  --levels $(if $(call cons_word,5,$*)$(filter-out fem,$(call cons_word,2,$*)),4,5) --no-vtk --no-plots -q --out $@.part && rm -rf $@ && mv $@.part $@

## compare: FEM vs HHO (SC / no SC) vs SIPG / NIPG on [CAMWA21] tests 1, 2,
## p = 1..4, T0..T4 (nested start), plus cold-start Newton counts of FEM and HHO
## -> results/compare/REPORT.md.  `make -j2 compare` runs the independent runs in parallel.
CMP_METHODS := fem hho hho-nosc sipg nipg
CMP_RUNS := $(foreach t,test1 test2,$(foreach m,$(CMP_METHODS),$(foreach p,1 2 3 4,results/compare/runs/$(t)-$(firstword $(subst -, ,$(m)))-p$(p)-nested$(if $(findstring nosc,$(m)),-nosc)))) \
            $(foreach t,test1 test2,$(foreach m,fem hho,$(foreach p,1 2 3 4,results/compare/runs/$(t)-$(m)-p$(p)-cold)))
.PHONY: compare
compare: $(CMP_RUNS)
	$(PY) -m ngcontact.studies.compare results/compare $(CMP_RUNS)

# NIPG P3/P4 stop at T3: their general (unsymmetric) sparse LU on T4 takes 5-10 min per level on 2 cores
cmp_levels = $(if $(filter nipg-p3 nipg-p4,$(word 2,$(subst -, ,$(1)))-$(word 3,$(subst -, ,$(1)))),4,5)
results/compare/runs/%: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact run $(word 1,$(subst -, ,$*)) --disc $(word 2,$(subst -, ,$*)) \
	  --order $(subst p,,$(word 3,$(subst -, ,$*))) --start $(word 4,$(subst -, ,$*)) \
	  $(if $(word 5,$(subst -, ,$*)),--no-condense) --levels $(call cmp_levels,$*) --no-vtk --no-plots -q --out $@.part && rm -rf $@ && mv $@.part $@

## inexact-study: direct / gmres / inexact / adaptive inexact semismooth Newton (GMRES + ILU) on the
## [JSC20] disk test, P1 and P2, 2k..35k elements, (gamma_alg, gamma_lin) table -> results/inexact/TABLES.md
.PHONY: inexact-study
inexact-study: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(PY) -m ngcontact.studies.inexact results/inexact

## adaptive-speed: wall / CPU time of adaptive vs inexact vs direct on the finest [JSC20] disk meshes (P1 35k,
## P2 27k), one process -> results/inexact/ADAPTIVE_SPEED.md (issue 24, item 4)
.PHONY: adaptive-speed
adaptive-speed: $(STAMP)
	NGCONTACT_THREADS=1 OPENBLAS_NUM_THREADS=1 $(PY) -m ngcontact.studies.adaptive_speed results/inexact

## sweep: uniform vs adaptive (Doerfler 0.5, bisection, warm start) FEM P1..P3 on lshape, test1,
## disk, disk_fitted, point_load; one independent target per run (`make -j2 sweep`; each run uses one NGSolve
## thread, so parallel runs do not distort each other's times; a run is redone when a file of ngcontact/ or cases/
## is newer than it); entries: ngcontact/studies/sweep.py SWEEP.
## report: reads only the sweep's CSVs -> results/REPORT.md + results/report/*.png
SWEEP_RUNS := $(foreach s,lshape test1 disk disk_fitted point_load,$(foreach m,uniform adaptive,$(foreach p,1 2 3,results/sweep/runs/$(s)-$(m)-p$(p))))
.PHONY: sweep report
sweep: $(SWEEP_RUNS)

# a run is redone when the package or the scenes changed since it was written
SWEEP_SRC := $(shell find ngcontact cases -name '*.py')
results/sweep/runs/%: $(STAMP) $(SWEEP_SRC)
	OPENBLAS_NUM_THREADS=1 $(PY) -m ngcontact.studies.sweep run $* $@.part && rm -rf $@ && mv $@.part $@

report: $(STAMP)
	$(PY) -m ngcontact.studies.sweep report results/sweep/runs results/REPORT.md results/report

## stability: the stability suite (stiff and extreme cases, one rule: converged with a valid certificate,
##            or a named reason; ngcontact/studies/stability.py) -> results/STABILITY.md (~4 min)
.PHONY: stability
stability: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact.studies.stability results/STABILITY.md

## stability-multigrid: the same cases with --newton multigrid (CG + multigrid in every Newton step, no
##            estimates) -> results/stability/MULTIGRID.md
.PHONY: stability-multigrid
stability-multigrid: $(STAMP)
	NGCONTACT_THREADS=1 OPENBLAS_NUM_THREADS=1 $(PY) -m ngcontact.studies.stability --newton multigrid results/stability/MULTIGRID.md

## bench: benchmarks (ex9 up to 1.05M unknowns, test1 ~1M nodes per membrane, each with sparse Cholesky and
##        with CG + multigrid (-mg); ~20 min, heavy) -> results/bench/*.csv + results/bench/BENCH.md;
##        estimator vs Newton time -> results/bench/ESTIMATE.md.
##        Not part of `make test`.
.PHONY: bench
bench: $(STAMP)
	$(PY) -m benchmarks.bench_contact --out results/bench
	$(PY) -m benchmarks.bench_estimate --out results/bench

## strip-study: width of the Dirichlet-correction strip (8 / 2 / 1 layers): I_eff and estimation time of
## uniform P2-P4 runs, time to 1e-5 of the adaptive L-shape P3 sweep entry -> results/estimators/STRIP_LAYERS.md
.PHONY: strip-study
strip-study: $(STAMP)
	NGCONTACT_THREADS=1 OPENBLAS_NUM_THREADS=1 $(PY) -m ngcontact.studies.strip_layers results/estimators

## estimator-study: eta, error, I_eff and every estimator part per level, FEM P1/P2, cold-start
## Newton to convergence: test1, test2 (T0..T4), test2_fitted (5 levels), disk and disk_fitted (4 levels)
## -> results/estimators/TABLES.md
EST_RUNS := $(foreach s,test1 test2 test2_fitted,$(foreach p,1 2,results/estimators/runs/$(s).p$(p).L5)) \
            $(foreach s,disk disk_fitted,$(foreach p,1 2,results/estimators/runs/$(s).p$(p).L4))
.PHONY: estimator-study
estimator-study: $(EST_RUNS)
	$(PY) -m ngcontact table $(EST_RUNS) --out results/estimators/TABLES.md

results/estimators/runs/%: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact run $(word 1,$(subst ., ,$*)) --order $(subst p,,$(word 2,$(subst ., ,$*))) \
	  --levels $(subst L,,$(word 3,$(subst ., ,$*))) --start cold --estimate --no-vtk --no-plots -q --out $@.part && rm -rf $@ && mv $@.part $@

## boundary-contact: estimator with contact on the Dirichlet boundary: err, eta, I_eff before/after the
## residual multiplier, P2/P3, T0..T4 (full_contact, obstacle_boundary) -> results/stability/BOUNDARY_CONTACT.md
.PHONY: boundary-contact
boundary-contact: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact.studies.boundary_contact --levels 5 --out results/stability/BOUNDARY_CONTACT.md

## twophase-study: water-hydrogen benchmark (MoMaS 1D, [CG20]): benchmark quantities, Newton-min/FB with
## direct / GMRES / inexact / adaptive solves, regularization and refinement -> results/twophase/REPORT.md
.PHONY: twophase-study
twophase-study: $(STAMP)
	rm -rf results/twophase.part
	OPENBLAS_NUM_THREADS=1 $(PY) -m ngcontact.studies.twophase results/twophase.part
	rm -rf results/twophase && mv results/twophase.part results/twophase

## parabolic-study: [CMAME20] tests 6.1 and 6.2 at the paper's sizes (P1 ~19k triangles, P2 ~4k, 300 steps),
## the manufactured solution (rates in h and dt, I_eff), adaptive time steps -> results/parabolic/REPORT.md
## (hours on 2 cores; finished experiments are cached in results/parabolic/runs/)
.PHONY: parabolic-study parabolic-study-quick
parabolic-study: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact.studies.parabolic results/parabolic --size full

## parabolic-study-quick: the same at the sizes that fit a short session -> results/parabolic/quick/REPORT.md
parabolic-study-quick: $(STAMP)
	NGCONTACT_THREADS=1 $(PY) -m ngcontact.studies.parabolic results/parabolic/quick --size quick
