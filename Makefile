# The two commands of the quick start: `make demo` and `make test`. Both set up .venv first
# (scripts/bootstrap.sh): `make demo` only what the demo and the nodes need (the runtime),
# `make test` that and every extra (cameras, Dask, test tools, chromium, the AVR toolchain,
# simavr, the firmware). `make camera` adds the real cameras' SDKs to the runtime.
.PHONY: demo test lint bootstrap bootstrap-test camera bench clean-venv

PYTEST_ARGS ?=

bootstrap:
	@bash scripts/bootstrap.sh

bootstrap-test:
	@bash scripts/bootstrap.sh --with test

camera:
	@bash scripts/bootstrap.sh --with camera

demo: bootstrap
	@ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST .venv/bin/lightstage demo

test: bootstrap-test lint
	@bash scripts/run_tests.sh $(PYTEST_ARGS)

# ruff (pinned in requirements-test.txt; rules in ruff.toml): fails `make test` before any test runs
lint: bootstrap-test
	@.venv/bin/ruff check

# every script in benchmarks/ run to its end with --quick (a small run of each; loopback only):
# a few minutes. `BENCH_ARGS= make bench` runs them in full (hours); docs/PERFORMANCE.md
bench: bootstrap-test
	@bash scripts/run_benchmarks.sh

clean-venv:
	rm -rf .venv .cache
