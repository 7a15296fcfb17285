# The two commands of the quick start: `make demo` and `make test`. Both set up .venv first
# (scripts/bootstrap.sh: Debian packages, pinned wheels, the interface build, the firmware).
.PHONY: demo test bootstrap bench clean-venv

PYTEST_ARGS ?=

bootstrap:
	@bash scripts/bootstrap.sh

demo: bootstrap
	@ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST .venv/bin/lightstage demo

test: bootstrap
	@bash scripts/run_tests.sh $(PYTEST_ARGS)

bench: bootstrap
	@for b in benchmarks/bench_*.py; do echo "== $$b"; .venv/bin/python $$b || exit 1; done

clean-venv:
	rm -rf .venv .cache
