"""Fixtures for the compiled AVR firmware running in simavr.

One harness per module (start-up builds the firmware if needed); every test gets the MCU
freshly reset (as opening a real Uno's port does), an open `Wire` and empty observations.
"""
import os

import pytest

from lightstage_driver.simavr_backend import SimavrBackend, missing_tools

from helpers.firmware_wire import Wire


@pytest.fixture(scope='module')
def avr():
    missing = missing_tools()
    if missing:
        reason = f'AVR toolchain / simavr not available: missing {", ".join(missing)}'
        # `make test` sets LIGHTSTAGE_REQUIRE_AVR: there this is a failure, not a skip.
        if os.environ.get('LIGHTSTAGE_REQUIRE_AVR'):
            pytest.fail(reason)
        pytest.skip(reason)
    backend = SimavrBackend()
    backend.start()
    yield backend
    backend.close()


@pytest.fixture
def wire(avr):
    avr.reset()
    link = Wire(avr.port)
    link.call(0x01, timeout_s=2.0)  # IDENTIFY: answered once the firmware has booted
    link.drain()
    avr.reset_observations()        # synced: the power-up clear of the chain goes too
    yield link
    link.close()
