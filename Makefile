# Two commands do all the set-up on a fresh machine (Python 3.11):
#   make demo   create .venv, install CPU torch + trioman[train,smplx,diffusion,viewer,fit,dev], run the demo
#   make test   the same install, then ruff check and the test suite
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
OUT    ?= out/demo
# The CPU build of torch; a bare "torch" would pull a multi-GB CUDA build.
TORCH  ?= torch==2.13.0
# The wheel that carries MediaPipe's pose models (trioman.runtime.person); installed without its dependencies.
MEDIAPIPE ?= mediapipe==0.10.21

.PHONY: demo lint test install clean models

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# Re-install when the project's metadata changes. $(MEDIAPIPE) carries the pose models of trioman.runtime.person
# and comes without its dependencies: its pins (numpy<2, protobuf<5, jax) would undo the rest (docs/fit.md).
$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[train,smplx,diffusion,viewer,fit,dev]"
	$(BIN)/pip install -q --no-deps "$(MEDIAPIPE)"
	touch $@

install: $(VENV)/.installed

demo: install
	$(BIN)/trioman demo --out $(OUT)

lint: install
	$(BIN)/ruff check .

# The runtime's tests run twice: with torch, and as on a machine without it (tests/conftest.py blocks the import).
test: lint
	$(BIN)/python -m pytest -q
	TRIOMAN_TEST_WITHOUT_TORCH=1 $(BIN)/python -m pytest -q tests/runtime

# The Refiner and Examiner the package ships (docs/models.md): a realistic corpus, both models trained on its
# training subjects, exported to ONNX (fp32, parity against torch on held-out triplets), copied into runtime/pretrained.
MODELS ?= out/models
models: install
	$(BIN)/trioman synth-corpus --out $(MODELS)/corpus --style realistic --subjects 8 --heldout 2 --baseline-frames subset --quiet
	$(BIN)/trioman train-refiner --corpus $(MODELS)/corpus --out $(MODELS)/refiner --conditions warp+geo --baseline-frames subset
	$(BIN)/trioman train-examiner --corpus $(MODELS)/corpus --out $(MODELS)/examiner --baseline-frames subset --validation-subjects 2
	$(BIN)/trioman export onnx --refiner $(MODELS)/refiner --examiner $(MODELS)/examiner --variants fp32 \
		--calibration $(MODELS)/corpus/triplets/heldout/*.npz --out $(MODELS)/onnx --overwrite
	$(BIN)/trioman export pretrained $(MODELS)/onnx --dest runtime/pretrained --heldout $(MODELS)/corpus/triplets/heldout/*.npz

clean:
	rm -rf $(VENV) out *.egg-info
