import pytest


@pytest.fixture(scope="session")
def critter():
    from puppet.rig import builtin

    return builtin()
