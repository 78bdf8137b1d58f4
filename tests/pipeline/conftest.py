import pytest

import dynamixel_sdk.port_handler as dxl_port


@pytest.fixture
def fast_timeouts():
    """Make SDK timeouts cost ~4 ms instead of ~34 ms (the module global the SDK reads)."""
    saved = dxl_port.LATENCY_TIMER
    dxl_port.LATENCY_TIMER = 1
    yield
    dxl_port.LATENCY_TIMER = saved


@pytest.fixture(scope="session")
def critter():
    from puppet.rig import builtin

    return builtin()
