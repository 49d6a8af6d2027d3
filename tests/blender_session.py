"""Fixtures shared by the Blender-side tests (import them into a test module)."""
import pytest

import photon_lightmaps
from photon_lightmaps import registration


@pytest.fixture(scope="session", autouse=True)
def addon():
    """Registers the add-on once per session, unless something already did."""
    owned = not registration.is_registered()
    if owned:
        photon_lightmaps.register()
    yield
    if owned:
        photon_lightmaps.unregister()
