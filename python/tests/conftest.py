"""Every test runs with the Vulkan validation layer on (and its synchronization validation when
VELLUM_SYNC_VALIDATION=1, as `make test` sets it), and fails if the layer reported anything."""

import os

os.environ.setdefault("VELLUM_VALIDATION", "1")

import pytest  # noqa: E402

import vellum  # noqa: E402


@pytest.fixture(autouse=True)
def validation_stays_silent():
    before = vellum.validation_messages()
    yield
    after = vellum.validation_messages()
    assert after == before, f"the validation layer reported (errors, warnings) {after}, {before} before"
