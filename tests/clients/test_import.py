"""Importing the client loads none of the heavy or server-side packages."""
from __future__ import annotations

import json
import subprocess
import sys

FORBIDDEN = ("cv2", "scipy", "fastapi", "starlette", "reglib", "service", "tqdm")


def test_import_loads_no_opencv_scipy_fastapi_or_reglib() -> None:
    code = ("import json, sys, reglib_client; "
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    loaded = set(json.loads(out.stdout))
    assert "reglib_client" in loaded and "httpx2" in loaded and "numpy" in loaded
    assert not loaded & set(FORBIDDEN), f"importing reglib_client loaded {sorted(loaded & set(FORBIDDEN))}"


def test_public_api_is_exported() -> None:
    import reglib_client

    for name in reglib_client.__all__:
        assert hasattr(reglib_client, name), name
    assert issubclass(reglib_client.TooLarge, reglib_client.ApiError)
    assert issubclass(reglib_client.InvalidInput, reglib_client.ApiError)
    assert issubclass(reglib_client.Overloaded, reglib_client.ApiError)
    assert issubclass(reglib_client.Timeout, reglib_client.ApiError)
