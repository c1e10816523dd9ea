# pf_slam: the two commands a user needs are `make run` (main job) and `make test`.
# Both set up whatever is missing first (scripts/setup.sh is idempotent and fast when done).
SHELL := /bin/bash
VENV ?= $(CURDIR)/.venv
BIN := $(VENV)/bin
SAMPLE_BAG ?= bags/sample_indoor
PARAMS ?= ros2_ws/src/pf_slam_nodes/config/sim_indoor.yaml
OUT ?= runs/sample
PYTEST_ARGS ?=

.PHONY: setup lint run test bench bench-car bench-scaling bench-thor lock clean

setup:
	@bash scripts/setup.sh

run: setup   ## the main job: the sample bag through the graph, then its error against ground truth
	$(BIN)/pf-slam run $(SAMPLE_BAG) --out $(OUT) --params $(PARAMS) --rate max
	$(BIN)/pf-slam eval --est $(OUT)/trajectory.tum --gt bags/ground_truth.tum

lint: setup   ## ruff: the linter and the formatter's check (ruff format . rewrites)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

test: setup lint
	$(BIN)/python -m pytest $(PYTEST_ARGS)

bench: setup   ## prints tables (also written to runs/bench/carmen*.md and docs/results.md): the CARMEN logs over 15 filter seeds in one process (five hid a lost run), seed 0 one process per node; the eight corrected-pose buildings and three simulated worlds x 10 seeds, the simulated ones also at 2 and 3 cm range noise and with a 0.25-degree 1081-beam laser x 5 seeds, ROS-free loop (~85 min here)
	$(BIN)/pf-slam bench messages --results docs/results.md
	$(BIN)/pf-slam bench carmen --data ../shared/data --out runs/bench --seeds 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 --results docs/results.md
	$(BIN)/pf-slam bench carmen --data ../shared/data --out runs/bench --seeds 0 --processes multi --results docs/results.md
	$(BIN)/pf-slam bench worlds --data ../shared/data --out runs/bench --seeds 0 1 2 3 4 5 6 7 8 9 --results docs/results.md \
	    --datasets acapulco belgioioso edmonton fhw freiburg-101 freiburg-campus orebro seattle
	$(BIN)/pf-slam bench worlds --data ../shared/data --out runs/bench --seeds 0 1 2 3 4 5 6 7 8 9 --results docs/results.md \
	    --datasets office corridors ring maze
	for noise in 0.02 0.03; do $(BIN)/pf-slam bench worlds --data ../shared/data --out runs/bench --seeds 0 1 2 3 4 \
	    --results docs/results.md --datasets office corridors ring --range-noise $$noise || exit 1; done
	$(BIN)/pf-slam bench worlds --data ../shared/data --out runs/bench --seeds 0 1 2 3 4 --results docs/results.md \
	    --datasets office corridors ring --laser 1081,270,30

bench-scaling: setup   ## particles 10-1000 (intel_2726) and grids 500²-4000² (intel_910): wall, RTF, peak RSS, stage split; plots in docs/img (~25 min)
	$(BIN)/pf-slam bench scaling --data ../shared/data --out runs/bench --plot-dir docs/img --results docs/results.md

bench-thor: setup   ## twenty simulated 60 s THOR walks (twenty office layouts) (moving head, RGB-D) x filter seeds 0 and 1: ATE, map F1, texture colour error, RTF
	$(BIN)/pf-slam bench thor --seeds 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 --filter-seeds 0 1 --out runs/bench --results docs/results.md

CAR_IMAGES ?= 1
CAR_FLAGS = $(if $(filter 0,$(CAR_IMAGES)),--no-images,)
bench-car: setup   ## car drives with stereo at 1 Hz (CAR_IMAGES=0: without): five 300 s drives x filter seeds 0, 1 (ATE, DR, map F1, RTF vs ceiling, pairs textured, colour error, coverage); five worlds drawn after the settings were chosen (46-50), 300 s x 2 filter seeds; thirty worlds' 180 s drives without images (wheel calibration errors, the scale estimate); one process per node
	$(BIN)/pf-slam bench car --seeds 0 1 2 3 4 --filter-seeds 0 1 $(CAR_FLAGS) --out runs/bench --results docs/results.md
	$(BIN)/pf-slam bench car --seeds 0 --worlds 46 47 48 49 50 --filter-seeds 0 1 --duration 300 $(CAR_FLAGS) --out runs/bench --results docs/results.md
	$(BIN)/pf-slam bench car --seeds 0 --worlds 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24 25 26 27 28 29 30 --filter-seeds 0 1 --duration 180 --no-images --out runs/bench --results docs/results.md
	$(BIN)/pf-slam bench car --seeds 0 $(CAR_FLAGS) --out runs/bench --processes multi --results docs/results.md

lock: setup   ## re-pin requirements/constraints.txt from the current venv
	@{ echo "# Lock file for the pip-only install: exact versions measured to work together (ROS 2 Jazzy wheels,"; \
	   echo "# rclpy 7.1.6). Regenerate with: make lock"; \
	   $(BIN)/pip freeze --all --exclude-editable --exclude pf-slam-interfaces --exclude tf2-msgs \
	     --exclude pf-slam-nodes --exclude pip | sort; } > requirements/constraints.txt

clean:
	rm -rf build runs $(VENV)
