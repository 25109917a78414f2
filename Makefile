# Set-up is a stamp file: the venv is (re)built only when pyproject.toml or constraints.txt change,
# so a second `make test` spends seconds on set-up.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.arcsem-installed
EXT     := $(VENV)/.arcsem-ext
CPP     := $(wildcard backbones/gaussians/cpp/*.cpp backbones/gaussians/cpp/*.h)
JOBS    ?= 2
export PIP_DISABLE_PIP_VERSION_CHECK=1

.PHONY: setup demo test clean-venv

setup: $(EXT)

$(STAMP): pyproject.toml constraints.txt examples/mip_splatting/pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[test]" -e examples/mip_splatting
	@touch $(STAMP)

# JIT-build the fused C++ rasteriser once (about a minute); failure is not fatal: PyTorch path is used.
$(EXT): $(STAMP) $(CPP)
	-$(BIN)/python -m arcsem.backbones.gaussians.fused
	@touch $(EXT)

demo: $(EXT)
	$(BIN)/arcsem experiment=demo

test: $(EXT)
	$(BIN)/python -m pytest -q -n $(JOBS) --dist loadgroup

clean-venv:
	rm -rf $(VENV)
