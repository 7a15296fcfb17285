"""Fixtures of the driver suite: one parametrized firmware backend, two implementations.

`backend` runs every test that takes it twice: against the Python firmware simulator
("python") and against the compiled AVR firmware in simavr ("avr",
`lightstage_driver.simavr_backend.SimavrBackend`, built by the firmware's `make`; skipped
with the reason when it is not importable or not built). Tests that need fault knobs use
`sim` (Python simulator only).
"""
from __future__ import annotations

import os

import pytest

from lightstage_driver.sim_backend import PythonSimBackend
from lightstage_driver.stage import LightStage

BACKENDS = ['python', 'avr']


def _unavailable(reason: str):
    # `make test` sets LIGHTSTAGE_REQUIRE_AVR: there a missing firmware rig is a failure,
    # not a silent skip of half the suite.
    if os.environ.get('LIGHTSTAGE_REQUIRE_AVR'):
        pytest.fail(reason)
    pytest.skip(reason)


def make_backend(kind: str):
    """A started backend of that kind (skips the test when the AVR one cannot run here)."""
    if kind == 'python':
        backend = PythonSimBackend()
        backend.start()
        return backend
    try:
        from lightstage_driver.simavr_backend import SimavrBackend
    except ImportError as exc:
        _unavailable(f'AVR backend not available (lightstage_driver.simavr_backend: {exc}); '
                    f'build the firmware harness with `make -C src/lightstage_driver/firmware`')
    try:
        backend = SimavrBackend()
        backend.start()
    except (FileNotFoundError, OSError, RuntimeError) as exc:
        _unavailable(f'AVR firmware under simavr could not start ({exc}); run its `make` first')
    return backend


@pytest.fixture(scope='module', params=BACKENDS)
def firmware(request):
    """A started backend shared by a module's tests (restarted if a test killed it)."""
    backend = make_backend(request.param)
    yield backend
    if hasattr(backend, 'close'):
        backend.close()
    else:
        backend.stop()


@pytest.fixture
def backend(firmware):
    if not firmware.running:
        firmware.start()
    firmware.reset_observations()
    yield firmware
    if not firmware.running:
        firmware.start()


@pytest.fixture
def stage(backend):
    stage = LightStage(backend.port, timeout_s=0.2, retries=3, connect_timeout_s=5.0)
    stage.connect()
    stage.set_watchdog(1000)   # a module-shared firmware may keep an earlier test's setting
    stage.all_off()
    backend.reset_observations()
    yield stage
    try:
        stage.close(all_off=True)
    except Exception:  # noqa: BLE001 - best effort: a test may have broken the line on purpose
        pass


@pytest.fixture
def sim():
    """A fresh Python simulator (fault injection), stopped after the test."""
    backend = PythonSimBackend()
    backend.start()
    yield backend
    backend.close()

