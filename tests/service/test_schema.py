"""A schemathesis run over the OpenAPI schema against a real uvicorn: no request may get a 5xx.

Examples are bounded (``max_examples``) and generation is derandomized, so the run is short and
repeatable. Every non-2xx answer must be a problem+json document.
"""
from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from service.app import create_app
from service.config import Settings

pytestmark = pytest.mark.slow

# The schema only; no pool is started to build it.
schema = schemathesis.openapi.from_dict(create_app(Settings(workers=1)).openapi())


@schema.parametrize()
@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.data_too_large])
def test_no_server_error(case, live_server):
    response = case.call(base_url=live_server.url, timeout=60)
    assert response.status_code < 500, \
        f"{case.method} {case.path}: {response.status_code} {response.text[:300]}"
    if response.status_code >= 400:
        content_type = response.headers.get("content-type", [""])[0]
        assert content_type.startswith("application/problem+json"), response.text[:200]
