"""reglib-client: call the reglib service from Python with numpy and httpx2 only.

>>> from reglib_client import Client                                   # doctest: +SKIP
>>> with Client("http://127.0.0.1:8000") as client:                   # doctest: +SKIP
...     result = client.match("a.png", "b.png")
...     print(result.n_inliers, result.transform(result.src[:3]))

Importing it loads neither OpenCV, SciPy, FastAPI nor reglib.
"""
from ._arrays import decode_flow
from ._client import DEFAULT_TIMEOUT, AsyncClient, Client, ProgressCallback, RetryPolicy
from ._png import decode_png, encode_png
from .bundle import MatchBundle
from .errors import (
    ApiError,
    InvalidInput,
    MalformedResponse,
    Overloaded,
    Timeout,
    TooLarge,
    Unauthorized,
    Unreachable,
)
from .results import (
    ConfidenceResult,
    FilterResult,
    FlowResult,
    Health,
    MatchResult,
    PairOutcome,
    RegisterResult,
    WarpResult,
)
from .transform import Transform

__version__ = "0.1.0"

__all__ = [
    "DEFAULT_TIMEOUT",
    "ApiError",
    "AsyncClient",
    "Client",
    "ConfidenceResult",
    "FilterResult",
    "FlowResult",
    "Health",
    "InvalidInput",
    "MalformedResponse",
    "MatchBundle",
    "MatchResult",
    "Overloaded",
    "PairOutcome",
    "ProgressCallback",
    "RegisterResult",
    "RetryPolicy",
    "Timeout",
    "TooLarge",
    "Transform",
    "Unauthorized",
    "Unreachable",
    "WarpResult",
    "decode_flow",
    "decode_png",
    "encode_png",
]
