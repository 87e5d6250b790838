# m2d2m: every verb bootstraps its own virtual environment, so a fresh clone needs only make and
# Python 3.11 to 3.14. Stages chain without arguments (each takes the newest output of the one before).

VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
M2D2M  := $(BIN)/m2d2m

# The interpreter .venv is made with: Python 3.11 to 3.14, pyproject.toml's requires-python (README, "Python
# versions"). Left out, PYTHON is the first of PYTHONS that runs, is one of those versions and has venv and
# ensurepip (Debian, Ubuntu: python3.x-venv), looked for only when .venv is to be made; 3.11 comes first, the
# version tested longest. `make PYTHON=python3.13 ...` (a name on PATH or a path) names one: a .venv of another
# Python version is then made again with it. Without PYTHON an existing .venv is kept, whatever its Python.
PYTHONS  := python3.11 python3.12 python3.13 python3.14 python3
PY_PROBE := import sys, venv, ensurepip; v = sys.version_info[:2]; print(*v, sep=".") if (3, 11) <= v < (3, 15) else exit(1)
py_version = $(shell $(1) -c '$(PY_PROBE)' 2>/dev/null)
ifeq ($(filter command line environment,$(origin PYTHON)),)
PYTHON = $(eval PYTHON := $(shell for p in $(PYTHONS); do $$p -c '$(PY_PROBE)' >/dev/null 2>&1 && { echo $$p; break; }; done))$(PYTHON)
else
PYTHON_VERSION := $(call py_version,$(PYTHON))
ifeq ($(PYTHON_VERSION),)
PYTHON_BAD := $(subst ",',$(shell $(PYTHON) -V 2>&1 | head -n 1))
PYTHON_BAD := $(or $(PYTHON_BAD),it says nothing)
else ifneq ($(wildcard $(BIN)/python),)
VENV_VERSION := $(call py_version,$(BIN)/python)
ifneq ($(VENV_VERSION),$(PYTHON_VERSION))
VENV_OTHER_PYTHON := 1
endif
endif
endif
# PYTHON names this project's interpreter, not that of a make which a verb's commands run (a test's make -n)
unexport PYTHON
MAKEOVERRIDES := $(filter-out PYTHON=%,$(MAKEOVERRIDES))
NO_PYTHON := echo "make: no Python 3.11-3.14 with venv found (tried $(PYTHONS)); install one (Debian, Ubuntu: \
	python3.x-venv) or name it: make PYTHON=/path/to/python3.x ..." >&2; exit 2

DATASET ?= synthetic
SET     ?=
# DATASET named on the command line also retargets the training and sweep configs: --set dataset=<it>
# (their data/<dataset> follows, docs/data.md), so a humanml3d config trains on humanml3d-public.
SETS     = $(foreach s,$(if $(filter command line environment,$(origin DATASET)),dataset=$(DATASET)) $(SET),--set $(s))
DATA_ARGS ?=
CLIPS   ?= 2000
SEED    ?= 0
RAW     ?= data/raw/$(DATASET)
DEMO    ?= runs/demo

.DEFAULT_GOAL := help
.PHONY: help setup models demo test test-all lint bench bench-gpu gpu-carry corpus data train-vq tokens train-diffusion train-mmm train-body-vq \
        train-mmm-body edit-upper train-motiondiffuse train-evaluator testset eval eval-power compare generate sweep \
        reproduce learning-curves ui serve blender-addon clean rebuild-venv demo-real

help:  ## list the verbs
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed 's/:.*## /\t/' | expand -t 18

# .venv runs the code of the folder it was made in: its console scripts' #! lines name that folder's
# interpreter and its editable install imports that folder's packages. The stamp records the folder; in a
# copy of the project (rsync to a cluster node, a renamed folder) it names another one, and .venv is made
# again. An older Makefile's stamp is empty: then .venv itself says where the m2d2m it imports lives.
VENV_OWNER := $(or $(file <$(STAMP)),$(shell $(BIN)/python -I -c 'import importlib.util as u, pathlib as p; \
	print(p.Path(u.find_spec("m2d2m").origin).parents[1])' 2>/dev/null))
ifneq ($(VENV_OWNER),$(CURDIR))
VENV_ELSEWHERE := 1
endif

VENV_REMAKE := $(or $(VENV_ELSEWHERE),$(VENV_OTHER_PYTHON),$(PYTHON_BAD))

# torch first, pinned, so that nothing resolves a CUDA build of several GB.
$(STAMP): pyproject.toml $(if $(VENV_REMAKE),rebuild-venv)
ifdef PYTHON_BAD
	@echo "make: PYTHON=$(PYTHON) is not a Python 3.11-3.14 with venv and ensurepip (Debian, Ubuntu: python3.x-venv): $(PYTHON_BAD)" >&2; exit 2
endif
ifdef VENV_ELSEWHERE
	@test ! -e $(BIN) || echo "$(VENV) belongs to $(or $(VENV_OWNER),another folder), not $(CURDIR): making it again"
endif
ifdef VENV_OTHER_PYTHON
	@echo "$(VENV) runs $(if $(VENV_VERSION),Python $(VENV_VERSION),no Python that works), not $(PYTHON_VERSION) (PYTHON=$(PYTHON)): making it again"
endif
ifdef VENV_REMAKE
	$(if $(PYTHON),$(PYTHON) -m venv --clear $(VENV),@$(NO_PYTHON))
else
	@test -x $(BIN)/python || { $(if $(PYTHON),$(PYTHON) -m venv $(VENV),$(NO_PYTHON)); }
endif
	$(BIN)/pip install --quiet --disable-pip-version-check torch==2.13.0
	$(BIN)/pip install --quiet --disable-pip-version-check -e ".[test]"
	@echo '$(CURDIR)' > $@

rebuild-venv:  # a prerequisite that is never up to date: .venv belongs to another folder or Python

setup: $(STAMP)  ## create .venv with the project and its test tools

DEMO_PROMPTS := "a person walks forward" "a person jumps" "a person waves their right hand" "a person sits down"
# A first look within the demo's 30 minutes: four methods twice on the 39 instances of n4-seed0 (about
# 4 minutes; at two repeats Jerk's t-interval is about ± 0.5). `make eval-power` sizes the comparison for 0.03
# (docs/evaluation.md, Power).
DEMO_REPEATS ?= 2
demo: $(STAMP)  ## the whole flow on the embedded synthetic corpus: data, models, evaluation, a clip, a sweep
ifeq ($(DATASET),bandai-namco)
	$(MAKE) --no-print-directory demo-real $(if $(filter command line environment,$(origin RAW)),REAL_RAW=$(RAW))
else ifneq ($(DATASET),synthetic)
	@echo "make demo: the flow of the embedded corpus or, with DATASET=bandai-namco, of real motion (make demo-real);" \
	"DATASET=$(DATASET) has none: make data, train-vq, train-diffusion ... with DATASET=$(DATASET) (docs/data.md)" >&2; exit 2
else
	$(M2D2M) synthesize --out data/raw/synthetic --clips $(CLIPS) --seed $(SEED)
	$(M2D2M) render data/raw/synthetic --id 000000 --out $(DEMO)/000000.gif
	$(M2D2M) export data/raw/synthetic --id 000000 --out $(DEMO)/000000.bvh
	$(M2D2M) data --dataset synthetic --raw data/raw/synthetic
	$(M2D2M) train-vq --config demo
	$(M2D2M) tokenize --dataset synthetic
	$(M2D2M) train-diffusion --config demo
	$(M2D2M) train-evaluator --config demo
	$(M2D2M) testset --dataset synthetic --n 4 --seed 0
	$(M2D2M) evaluate --dataset synthetic --method tps,independent,handshake,slerp --repeats $(DEMO_REPEATS)
	$(M2D2M) generate $(DEMO_PROMPTS) --out $(DEMO) --name four-actions
	$(M2D2M) testset --dataset synthetic --n 4 --seed 1 --first 12
	$(M2D2M) sweep --config demo
	@echo "Look at $(DEMO)/000000.gif (a corpus clip) and $(DEMO)/four-actions.gif (four actions by TPS);"
	@echo "import the .bvh files into Blender (scale 1 = metres). The evaluation's table and Fig. 5 are in"
	@echo "runs/synthetic/eval/<run>/, the sweep's summary in runs/synthetic/sweep/demo/."
	@echo "Type your own actions and compare methods side by side on a page: make serve (http://127.0.0.1:8000)"
	@echo "Compare every run (the sweep's trials are child runs of one parent) in the MLflow UI: make ui"
	@echo "For TPS against independent sampling with Jerk half-widths of 0.03 (about 20 minutes): make eval-power"
endif

test: $(STAMP)  ## the fast test loop (tests marked slow, or that start Ray or a browser, left to test-all)
	$(BIN)/pytest -m "not slow"

lint: $(STAMP)  ## check formatting and lint (ruff, pyproject.toml); `.venv/bin/ruff format .` fixes formatting
	$(BIN)/ruff format --check .
	$(BIN)/ruff check .

test-all: $(STAMP)  ## run every test, slow end-to-end ones included
	$(BIN)/pytest

bench: $(STAMP)  ## measure speed; results go to BENCHMARKS.md by hand
	$(BIN)/python bench/representation.py
	$(BIN)/python bench/pipeline.py
	$(BIN)/python bench/train_vq.py
	$(BIN)/python bench/discrete_diffusion.py
	$(BIN)/python bench/sampling.py
	$(BIN)/python bench/aits.py --dataset $(DATASET)
	$(BIN)/python bench/attention.py
	$(BIN)/python bench/serve.py --dataset $(DATASET)

bench-gpu: $(STAMP)  ## training, sampling and the long sequence of every model on this machine's GPU, bf16 (BENCH_GPU_ARGS=--quick on a CPU)
	$(BIN)/python bench/gpu.py $(BENCH_GPU_ARGS)

gpu-carry: $(STAMP)  ## what a bare GPU machine is given for the GPU bench: .carry/ (wheels and a demo project; bench/gpu_run.sh runs it there)
	$(BIN)/python bench/gpu_carry.py

corpus: $(STAMP)  ## generate the embedded synthetic corpus (CLIPS, SEED) into data/raw/synthetic
	$(M2D2M) synthesize --out $(RAW) --clips $(CLIPS) --seed $(SEED)

data: $(STAMP)  ## preprocess a corpus into WebDataset shards (DATASET=synthetic|humanml3d|kit|humanml3d-public|bvh, RAW=dir, DATA_ARGS="--bvh DIR")
	$(M2D2M) data --dataset $(DATASET) --raw $(RAW) $(DATA_ARGS)

VQ_CONFIG ?= demo
train-vq: $(STAMP)  ## train the motion VQ-VAE (VQ_CONFIG=demo|humanml3d|kit, SET="key=value ...")
	$(M2D2M) train-vq --config $(VQ_CONFIG) $(SETS)

tokens: $(STAMP)  ## encode every motion with the latest VQ-VAE into token shards
	$(M2D2M) tokenize --dataset $(DATASET)

DIFFUSION_CONFIG ?= demo
train-diffusion: $(STAMP)  ## train the denoiser with beta(t, d) (DIFFUSION_CONFIG=demo|humanml3d|kit, SET=...); tokenizes first if needed
	$(M2D2M) train-diffusion --config $(DIFFUSION_CONFIG) $(SETS)

MMM_CONFIG ?= demo
train-mmm: $(STAMP)  ## train MMM's masked transformer on the latest VQ run's tokens, the demo's by default (MMM_CONFIG=demo|humanml3d|kit, SET=...)
	$(M2D2M) train-mmm --config $(MMM_CONFIG) $(SETS)

BODY_VQ_CONFIG ?= demo
train-body-vq: $(STAMP)  ## train MMM's upper- and lower-body tokenizers (configs/vq/mmm-{upper,lower}-$(BODY_VQ_CONFIG).yaml: demo|humanml3d|kit; SET=...)
	$(M2D2M) train-vq --config mmm-upper-$(BODY_VQ_CONFIG) $(SETS)
	$(M2D2M) train-vq --config mmm-lower-$(BODY_VQ_CONFIG) $(SETS)

MMM_BODY_CONFIG ?= demo
train-mmm-body: $(STAMP)  ## train MMM's upper-body editor on the latest part tokenizers' tokens (make train-body-vq first; MMM_BODY_CONFIG=demo|humanml3d|kit, SET=...)
	$(M2D2M) train-mmm-body --config $(MMM_BODY_CONFIG) $(SETS)

SOURCE ?=
EDIT_PROMPT ?= "a person waves their right hand"
edit-upper: $(STAMP)  ## new upper body for a motion, its lower body kept (SOURCE=motion.features.npy EDIT_PROMPT='"a person claps"' GENERATE_ARGS="--option lower_mask=0.25")
	@test -n "$(SOURCE)" || { echo "make edit-upper: give SOURCE=<a .npy of features or joints>, e.g. a generation's motion.features.npy" >&2; exit 2; }
	$(M2D2M) generate $(EDIT_PROMPT) --model mmm-body --dataset $(DATASET) --edit $(SOURCE) --keep-body lower $(GENERATE_ARGS)

MOTIONDIFFUSE_CONFIG ?= demo
train-motiondiffuse: $(STAMP)  ## train MotionDiffuse on the dataset's features (MOTIONDIFFUSE_CONFIG=demo|humanml3d|kit, SET=...)
	$(M2D2M) train-motiondiffuse --config $(MOTIONDIFFUSE_CONFIG) $(SETS)

PROMPTS ?= "a person walks forward" "a person jumps" "a person sits down"
GENERATE_ARGS ?=
generate: $(STAMP)  ## text to motion with the latest denoiser (PROMPTS='"a person walks" "a person jumps"', GENERATE_ARGS="--method tps --seconds 4")
	$(M2D2M) generate $(PROMPTS) --dataset $(DATASET) $(GENERATE_ARGS)

EVALUATOR_CONFIG ?= demo
train-evaluator: $(STAMP)  ## train the text-motion evaluator for the metrics (EVALUATOR_CONFIG=demo|humanml3d|kit, SET=...)
	$(M2D2M) train-evaluator --config $(EVALUATOR_CONFIG) $(SETS)

UI_PORT ?= 5000
SERVE_ARGS ?=
serve: $(STAMP)  ## the page and HTTP API at http://127.0.0.1:8000 (after make demo; SERVE_ARGS="--port 8080 --host 0.0.0.0 --token ...")
	$(M2D2M) serve --dataset $(DATASET) $(SERVE_ARGS)

blender-addon:  ## the Blender add-on as dist/m2d2m_blender.zip, to install in Blender (docs/generation.md, "In Blender")
	python3 integrations/blender/pack.py dist/m2d2m_blender.zip

models: $(STAMP)  ## what each trained model knows (every dataset's, or DATASET=...): its actions, lengths, words, methods and sampling defaults
	$(M2D2M) models $(if $(filter command line environment,$(origin DATASET)),--dataset $(DATASET))

ui: $(STAMP)  ## the MLflow UI on the project's tracking store (UI_PORT=5000)
	$(M2D2M) ui --port $(UI_PORT)

N       ?= 4
MIRRORS ?= same
testset: $(STAMP)  ## build the N-action test set of the multi-motion evaluation (N=4 SEED=0 MIRRORS=same|distinct|exclude)
	$(M2D2M) testset --dataset $(DATASET) --n $(N) --seed $(SEED) --mirrors $(MIRRORS)

MODELS    ?= m2d2m
METHODS   ?= tps,independent,handshake,slerp
REPEATS   ?= 10
RESUME    ?=
EVAL_ARGS ?=
eval: $(STAMP)  ## the paper's multi-motion table + Fig. 5 of the latest denoiser (MODELS=m2d2m,mmm METHODS=...,mmm:transition REPEATS=10 EVAL_ARGS="--single --edit inbetween", RESUME=<run>)
	$(M2D2M) evaluate --dataset $(DATASET) $(if $(RESUME),--resume $(RESUME),--model $(MODELS) --method $(METHODS) --repeats $(REPEATS)) $(EVAL_ARGS)

# Sized by bench/tps_boundaries.py on the demo model: a sequence's Jerk varies by 0.31-0.41 from seed to
# seed, so 10 repeats of 78 instances give half-widths of 1.96 * σ / sqrt(780) = 0.022-0.029.
POWER_METHODS ?= tps,independent
POWER_REPEATS ?= 10
POWER_TESTSET := data/$(DATASET)/testsets/n4-seed0-distinct
eval-power: $(STAMP)  ## the multi-motion table with Jerk half-widths <= 0.03: 78 instances x 10 repeats (POWER_METHODS=tps,independent; about 10 min a method)
	$(M2D2M) testset --dataset $(DATASET) --n 4 --seed 0 --mirrors distinct
	$(M2D2M) evaluate --dataset $(DATASET) --testset $(POWER_TESTSET) --method $(POWER_METHODS) --repeats $(POWER_REPEATS)

# The three seed systems on the embedded default, each trained only if it has no finished run yet, judged in one
# evaluate run. MotionDiffuse samples with 25 of its 1000 steps here (respaced; on the demo's x0 model 25 steps
# gave R-Top3 0.70 / FID 10.4 against 100 steps' 0.64 / 7.9 at a quarter of the time; COMPARE_MD_STEPS=1000 for
# the paper's): docs/reproduction.md, "MotionDiffuse on the same curves".
COMPARE_REPEATS  ?= 2
COMPARE_MD_STEPS ?= 25
COMPARE_METHODS  := m2d2m:tps,m2d2m:independent,m2d2m:handshake,m2d2m:slerp,mmm:transition,motiondiffuse:time-varied
COMPARE_ARGS     ?=
compare: $(STAMP)  ## M2D2M, MMM and MotionDiffuse trained (what is missing) and judged in one evaluate run (COMPARE_REPEATS=2 COMPARE_MD_STEPS=25; COMPARE_ARGS="--regenerate 3" adds the timeline-editing table)
	@test -f data/synthetic/manifest.json || { $(M2D2M) synthesize --out data/raw/synthetic --clips $(CLIPS) --seed $(SEED) \
		&& $(M2D2M) data --dataset synthetic --raw data/raw/synthetic; }
	@test -f runs/synthetic/vq/latest || $(M2D2M) train-vq --config demo
	@test -f runs/synthetic/m2d2m/latest || $(M2D2M) train-diffusion --config demo
	@test -f runs/synthetic/mmm/latest || $(M2D2M) train-mmm --config demo
	@test -f runs/synthetic/motiondiffuse/latest || $(M2D2M) train-motiondiffuse --config demo
	@test -f runs/synthetic/evaluator/latest || $(M2D2M) train-evaluator --config demo
	$(M2D2M) testset --dataset synthetic --n 4 --seed 0
	$(M2D2M) evaluate --dataset synthetic --model m2d2m,mmm,motiondiffuse --method $(COMPARE_METHODS) --single \
		--repeats $(COMPARE_REPEATS) --option motiondiffuse.steps=$(COMPARE_MD_STEPS) $(COMPARE_ARGS)

# Real motion: the Bandai Namco Research Motion Dataset (CC BY-NC 4.0, non-commercial), cloned beside this
# project, built into data/bandai-namco and learned by every model at the demo's sizes (configs/*/bandai-namco.yaml),
# then the seed systems judged in one evaluate run on its 4-action test set (docs/reproduction.md, "On real motion").
REAL_RAW     ?= ../Bandai-Namco-Research-Motiondataset
REAL_REPEATS ?= 5
REAL_PROMPTS := "a person walks forward" "a person bows" "a person waves the right hand" "a person runs forward"
demo-real: $(STAMP)  ## the whole flow on real motion capture: the Bandai Namco corpus (REAL_RAW=its clone, default beside this folder), the four models, their table
	@test -d "$(REAL_RAW)" || { echo "make demo-real: no Bandai Namco clone at $(REAL_RAW); git clone \
	https://github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset $(REAL_RAW) (or REAL_RAW=its path)" >&2; exit 2; }
	$(M2D2M) data --dataset bandai-namco --raw $(REAL_RAW)
	$(M2D2M) train-vq --config bandai-namco
	$(M2D2M) tokenize --dataset bandai-namco
	$(M2D2M) train-diffusion --config bandai-namco
	$(M2D2M) train-mmm --config bandai-namco
	$(M2D2M) train-motiondiffuse --config bandai-namco
	$(M2D2M) train-evaluator --config bandai-namco
	$(M2D2M) testset --dataset bandai-namco --n 4 --seed 0
	$(M2D2M) evaluate --dataset bandai-namco --model m2d2m,mmm,motiondiffuse --method $(COMPARE_METHODS) --single \
		--repeats $(REAL_REPEATS) --option motiondiffuse.steps=$(COMPARE_MD_STEPS)
	$(M2D2M) generate $(REAL_PROMPTS) --dataset bandai-namco --out $(DEMO)-real --name four-actions
	@echo "Look at $(DEMO)-real/four-actions.gif; the table is in runs/bandai-namco/eval/<run>/table.md."
	@echo "Type your own actions on the real-motion models: make serve DATASET=bandai-namco"

SWEEP_CONFIG ?= demo
RAY_ADDRESS_ARG ?=
sweep: $(STAMP)  ## Ray Tune sweep (SWEEP_CONFIG=demo: 2 eta x 3 T_s on the latest denoiser; SET=...; RAY_ADDRESS_ARG="--ray-address auto")
	$(M2D2M) sweep --config $(SWEEP_CONFIG) $(SETS) $(RAY_ADDRESS_ARG)

REPRODUCE_ARGS ?=
reproduce: $(STAMP)  ## the paper's Tables 5, 6 and a T_s curve on the embedded default with the paper's exact setting (configs/m2d2m/paper-demo.yaml), trained twice as long as the demo (about 100 min on 2 CPU cores; REPRODUCE_ARGS="--quick")
	$(BIN)/python bench/reproduce.py $(REPRODUCE_ARGS)

CURVES_ARGS ?= --curves m2d2m mmm --ablation
learning-curves: $(STAMP)  ## M2D2M's and MMM's learning curves on the same tokens and M2D2M's ablation, after make demo (hours on 2 CPU cores; CURVES_ARGS="--quick", "--curves m2d2m mmm motiondiffuse")
	$(BIN)/python bench/learning_curves.py $(CURVES_ARGS)

clean:  ## remove generated data and runs (keeps .venv)
	rm -rf data runs mlruns mlflow.db
