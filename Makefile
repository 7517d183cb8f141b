# Every target creates/updates .venv as needed (stamp file tracks pyproject.toml).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= runs
SEEDS ?= 20
BUDGET_SEEDS ?= 40
CAL_SEEDS ?= 10
# issue 13's operating envelope (300 runs, ~75 min on 2 cores): appearance x water x standoff, 5 seeds
ENVELOPE_GRID := --param 'site.textures=[{}, {backplate: data/textures/industrial_rocket_launch.jpg}, \
	{backplate: data/textures/natural_gravel.png}, {backplate: data/textures/lowtexture_cameraman.png}, \
	{backplate: data/textures/repetitive_brick.png}]' \
	--param site.water=clear_ocean,coastal,turbid_harbour --param site.standoff_m=0.5,0.7,1.0,1.5
# the Table 3 sweeps: the extractor comparison and the plots are the single run's
CAL_SWEEP := --set pipeline.compare_extractors=false --set outputs.plots=false --set outputs.rerun=false
# Headless rendering through Mesa's EGL (Debian: libegl1 libgl1-mesa-dri).
export MUJOCO_GL ?= egl

.PHONY: demo test reproduce benchmark docs screenshots lint venv clean

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev,cluster]"
	@touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/bench run scenarios/ta40_in_situ_manifold.yaml --out $(OUT)/demo

# the suite runs on TEST_WORKERS processes (pytest-xdist; a test file stays in one process, so its module fixtures
# are built once), each with one BLAS thread: the tests' linear algebra is small, and OpenBLAS's threads spin against
# anything else on a shared 2-core machine (the x-y bound's Monte Carlo test: 164 s with them, 42 s without, beside
# two sweeps). One process left the second core idle: 1,238 s on a fresh clone, against 825 s with two (this checkout,
# the same day).
TEST_WORKERS ?= 2
test: $(STAMP)
	$(BIN)/ruff check bench tests tools
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n $(TEST_WORKERS) \
		--dist loadfile

reproduce: $(STAMP)
	$(BIN)/bench run scenarios/table2_kinematic_identification.yaml --out $(OUT)/table2 --set monte_carlo.seeds=500
	$(BIN)/bench run scenarios/tracker_base_frame.yaml --out $(OUT)/tracker_base_frame
	$(BIN)/bench sweep scenarios/ta40_in_situ_manifold.yaml --seeds $(SEEDS) --seed 1 --out $(OUT)/sweep-insitu
	$(BIN)/bench sweep scenarios/ta40_in_situ_manifold.yaml --seeds $(SEEDS) --seed 1 --out $(OUT)/sweep-insitu-air \
		--set camera.preset=air_webcam
	$(BIN)/bench sweep scenarios/ta40_in_situ_manifold.yaml --seeds $(SEEDS) --seed 1 --out $(OUT)/sweep-insitu-ideal \
		--set camera.imaging=ideal
	$(BIN)/bench budget scenarios/ta40_in_situ_manifold.yaml --seeds $(BUDGET_SEEDS) --seed 1 --out $(OUT)/budget-insitu
	$(BIN)/bench sweep scenarios/ta40_envelope.yaml --seeds 5 --seed 1 --set camera.supersample=1 $(ENVELOPE_GRID) \
		--out $(OUT)/envelope
	$(BIN)/bench run scenarios/xy_table_webcam.yaml --out $(OUT)/xy_table_webcam
	$(BIN)/bench run scenarios/xy_table_underwater.yaml --out $(OUT)/xy_table_underwater
	$(BIN)/bench sweep scenarios/xy_table_webcam.yaml --seeds $(SEEDS) --seed 1 --out $(OUT)/sweep-xy_table_webcam
	$(BIN)/bench sweep scenarios/xy_table_underwater.yaml --seeds $(SEEDS) --seed 1 --out $(OUT)/sweep-xy_table_underwater
	$(BIN)/bench sweep scenarios/xy_table_webcam.yaml --seeds $(SEEDS) --seed 1 --out $(OUT)/sweep-xy_table_webcam-ideal \
		--set sim.imaging=ideal
	$(BIN)/bench run scenarios/camera_calibration_webcam.yaml --out $(OUT)/camera_calibration_webcam
	$(BIN)/bench run scenarios/camera_calibration_webcam.yaml --out $(OUT)/camera_calibration_webcam-ideal \
		--set camera.imaging=ideal
	$(BIN)/bench sweep scenarios/camera_calibration_webcam.yaml --seeds $(CAL_SEEDS) --seed 1 \
		--out $(OUT)/sweep-camera_calibration_webcam $(CAL_SWEEP)
	$(BIN)/bench sweep scenarios/camera_calibration_webcam.yaml --seeds $(CAL_SEEDS) --seed 1 \
		--out $(OUT)/sweep-camera_calibration_webcam-ideal $(CAL_SWEEP) --set camera.imaging=ideal
	$(BIN)/bench sweep scenarios/real_webcam_replica.yaml --seeds $(CAL_SEEDS) --seed 1 \
		--out $(OUT)/sweep-real_webcam_replica --set outputs.images=false
	$(BIN)/bench run scenarios/camera_calibration_underwater.yaml --out $(OUT)/camera_calibration_underwater
	$(BIN)/bench run scenarios/flatport_study.yaml --out $(OUT)/flatport_study
	$(BIN)/bench run scenarios/flatport_study.yaml --out $(OUT)/flatport_study_k3 --set calibration.k3=true
	$(BIN)/python tools/results_report.py --runs $(OUT)
	$(BIN)/python tools/screenshots.py --runs $(OUT)/screenshots

benchmark: $(STAMP)
	$(BIN)/python tools/benchmark.py --out $(OUT)/benchmark.json
	@$(BIN)/python -c "import figaroh" 2>/dev/null || $(BIN)/python -m pip install -q -e ".[figaroh]"
	OPENBLAS_NUM_THREADS=1 $(BIN)/python tools/figaroh_compare.py --out $(OUT)/figaroh_compare.json

docs: $(STAMP)
	$(BIN)/python tools/gen_reference.py

# The rerun viewer's default layout of each kind's recording, headless (needs xvfb and mesa-vulkan-drivers).
screenshots: $(STAMP)
	$(BIN)/python tools/screenshots.py --runs $(OUT)/screenshots

lint: $(STAMP)
	$(BIN)/ruff check bench tests tools

clean:
	rm -rf $(VENV) $(OUT)
