"""``Client`` and ``AsyncClient``: the service's endpoints as typed method calls.

Both share the request building and response reading below; only sending (with retries) and
``match_many`` differ between the blocking and the asyncio flavour.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import email.utils
import logging
import math
import os
import random
import time
from collections.abc import (
    AsyncIterator,
    Callable,
    Hashable,
    Iterable,
    Iterator,
    Mapping,
)
from dataclasses import dataclass
from datetime import UTC, datetime
from types import MappingProxyType
from typing import Any, Generic, TypeVar

import httpx2
import numpy as np

from ._arrays import decode_flow, decode_image
from ._inputs import (
    ImageInput,
    form_fields,
    image_part,
    json_options,
    points_json,
    scan_json,
)
from .bundle import MatchBundle
from .errors import ApiError, MalformedResponse, Timeout, Unreachable, error_for
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

__all__ = ["Client", "AsyncClient", "RetryPolicy", "DEFAULT_TIMEOUT", "ProgressCallback", "API_KEY_ENV"]

log = logging.getLogger("reglib_client")

#: Connect within 10 s; allow 120 s for the answer (more than the service's default compute limit
#: of 60 s, so a slow request ends in the server's 504 with a reason rather than a client timeout).
DEFAULT_TIMEOUT = httpx2.Timeout(120.0, connect=10.0)

#: What ``match_many`` takes: a sequence of ``(a, b)`` or a mapping of key -> ``(a, b)``.
PairInput = Iterable[tuple[ImageInput, ImageInput]] | Mapping[Hashable, tuple[ImageInput, ImageInput]]
#: ``progress(done, total)``; ``total`` is None when the pairs were an iterator of unknown length.
ProgressCallback = Callable[[int, "int | None"], None]

_RETRY_STATUS = (429, 503)
# Failures to connect or broken connections; the request can be sent again (every endpoint is a
# pure computation). Read / write / pool timeouts are not retried: the server may still be working.
_RETRY_EXC = (httpx2.ConnectError, httpx2.ConnectTimeout, httpx2.ReadError, httpx2.WriteError,
              httpx2.RemoteProtocolError, httpx2.CloseError)

_sleep = time.sleep
# ``timeout`` not given: DEFAULT_TIMEOUT for a client we build, the caller's own for an ``http_client``.
_UNSET: Any = object()
_async_sleep = asyncio.sleep
#: The environment variable an ``api_key`` left out is read from.
API_KEY_ENV = "REGLIB_API_KEY"


@dataclass(frozen=True, slots=True, kw_only=True)
class RetryPolicy:
    """When and how long to wait before sending a request again.

    Retried: connection failures, and 429 / 503 answers (waiting at least their ``Retry-After``).
    Never retried: other 4xx, 5xx other than 503, and read timeouts.

    Parameters
    ----------
    retries : int
        Attempts after the first one (0 turns retrying off).
    backoff : float
        Base delay in seconds; retry k waits about ``backoff * 2**k``, with jitter: a uniform
        draw from the upper half of that, capped at ``max_backoff``.
    max_backoff : float
        Cap of one backoff delay, in seconds.
    max_retry_after : float
        A ``Retry-After`` longer than this is not waited for: the error is raised at once (its
        ``retry_after`` attribute says how long the server asked for).
    """

    retries: int = 3
    backoff: float = 0.5
    max_backoff: float = 30.0
    max_retry_after: float = 120.0

    def __post_init__(self) -> None:
        if isinstance(self.retries, bool) or not isinstance(self.retries, int) or self.retries < 0:
            raise ValueError(f"`retries` must be an integer >= 0, got {self.retries!r}")
        for name in ("backoff", "max_backoff", "max_retry_after"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise ValueError(f"`{name}` must be a finite number >= 0, got {value!r}")

    def delay(self, retry: int, retry_after: float | None, rng: random.Random) -> float:
        """Seconds to wait before retry number ``retry`` (0-based)."""
        ceiling = min(self.max_backoff, self.backoff * 2.0 ** retry)
        wait = rng.uniform(ceiling / 2.0, ceiling)
        return wait if retry_after is None else max(wait, retry_after)


def _retry_after(response: httpx2.Response) -> float | None:
    """``Retry-After`` in seconds (delta-seconds or an HTTP date), None when absent or unreadable."""
    value = response.headers.get("retry-after")
    if value is None:
        return None
    value = value.strip()
    if value.isdigit():
        return float(value)
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError, IndexError):
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return max(0.0, (when - datetime.now(UTC)).total_seconds())


def _error_from_response(response: httpx2.Response) -> ApiError:
    """The :class:`ApiError` subclass for an error response, from its problem+json body when it has one."""
    status = response.status_code
    body: dict[str, Any] = {}
    try:
        parsed = response.json()
        if isinstance(parsed, dict):
            body = parsed
    except ValueError:
        pass
    def text(key: str, default: str) -> str:
        value = body.get(key)
        return value if isinstance(value, str) else default

    detail = text("detail", "" if body or not response.content else response.text[:500])
    return error_for(status)(status, text("type", "about:blank"), detail, text("title", response.reason_phrase),
                             retry_after=_retry_after(response), body=body)


def _json(response: httpx2.Response) -> Any:
    try:
        return response.json()
    except ValueError as exc:
        raise MalformedResponse(response.status_code, detail=f"the response is not JSON: {exc}",
                                title="Malformed response") from None


def _read(response: httpx2.Response, reader: Callable[[httpx2.Response], R]) -> R:
    try:
        return reader(response)
    except ApiError:
        raise
    except (ValueError, TypeError, KeyError) as exc:
        raise MalformedResponse(response.status_code, detail=str(exc), title="Malformed response") from None


R = TypeVar("R")


@dataclass(frozen=True, slots=True)
class _Call(Generic[R]):
    """One request, as built from a method's arguments, and how to read its answer."""

    method: str
    path: str
    read: Callable[[httpx2.Response], R]
    json: Any = None
    data: dict[str, str] | None = None
    files: dict[str, tuple[str, bytes, str]] | None = None


def _auth_headers(api_key: str | None) -> dict[str, str]:
    """``Authorization: Bearer <key>`` for ``api_key``, else for ``$REGLIB_API_KEY``; none when neither is set."""
    if api_key is None:
        api_key = os.environ.get(API_KEY_ENV, "").strip() or None
        if api_key is None:
            return {}
        where = f"${API_KEY_ENV}"
    else:
        where = "`api_key`"
    if not isinstance(api_key, str) or not api_key or not all("!" <= ch <= "~" for ch in api_key):
        shown = type(api_key).__name__ if not isinstance(api_key, str) else f"{len(api_key)} characters"
        raise ValueError(f"{where} must be one word of printable ASCII (the key, without 'Bearer'), got {shown}")
    return {"Authorization": f"Bearer {api_key}"}


def _method_seed(method: str | None, seed: int | None) -> dict[str, Any]:
    """Top-level ``method`` / ``seed`` of a JSON body; left out when None (the server's default applies)."""
    return {key: value for key, value in (("method", method), ("seed", seed)) if value is not None}


class _Base:
    """Request building and response reading, shared by both clients."""

    def __init__(self, base_url: str, *, timeout: float | httpx2.Timeout | None,
                 retries: int | RetryPolicy, own_http: bool, api_key: str | None = None) -> None:
        if not isinstance(base_url, str) or not base_url.startswith(("http://", "https://")):
            raise ValueError(f"`base_url` must be an http:// or https:// URL, got {base_url!r}")
        self.base_url = base_url.rstrip("/")
        # With a caller's http_client and no explicit timeout, requests use that client's timeout.
        self._per_request_timeout = timeout is not _UNSET
        if timeout is _UNSET:
            timeout = DEFAULT_TIMEOUT if own_http else None
        if isinstance(timeout, (int, float)) and not isinstance(timeout, bool):
            if not math.isfinite(timeout) or timeout <= 0:
                raise ValueError(f"`timeout` must be a positive number of seconds, got {timeout!r}")
            timeout = httpx2.Timeout(float(timeout))
        elif timeout is not None and not isinstance(timeout, httpx2.Timeout):
            raise TypeError(f"`timeout` must be seconds, an httpx2.Timeout or None, got {type(timeout).__name__}")
        self.timeout = httpx2.Timeout(None) if timeout is None else timeout
        self.retry = retries if isinstance(retries, RetryPolicy) else RetryPolicy(retries=retries)
        self._rng = random.Random()
        self._headers = _auth_headers(api_key)  # never shown: no repr names it

    def _url(self, path: str) -> str:
        return self.base_url + path

    # ------------------------------------------------------------------ requests
    @staticmethod
    def _image_call(path: str, image_a: ImageInput, image_b: ImageInput, options: dict[str, Any],
                    read: Callable[[httpx2.Response], R]) -> _Call[R]:
        files = {"image_a": image_part(image_a, "image_a"), "image_b": image_part(image_b, "image_b")}
        return _Call("POST", path, read, data=form_fields(options), files=files)

    def _match_call(self, image_a: ImageInput, image_b: ImageInput, options: dict[str, Any]) -> _Call[MatchResult]:
        return self._image_call("/v1/match", image_a, image_b, options,
                                lambda r: MatchResult.from_json(_json(r)))

    def _bundle_call(self, image_a: ImageInput, image_b: ImageInput,
                     options: dict[str, Any]) -> _Call[MatchBundle]:
        return self._image_call("/v1/match/bundle", image_a, image_b, options,
                                lambda r: MatchBundle.from_json(_json(r)))

    def _warp_call(self, image_a: ImageInput, image_b: ImageInput, options: dict[str, Any]) -> _Call[WarpResult]:
        def read(response: httpx2.Response) -> WarpResult:
            return WarpResult(image=decode_image(response.content), content=response.content,
                              media_type=response.headers.get("content-type", ""))
        return self._image_call("/v1/warp", image_a, image_b, options, read)

    def _flow_call(self, image_a: ImageInput, image_b: ImageInput, options: dict[str, Any]) -> _Call[FlowResult]:
        fmt = options.get("format")
        if fmt not in (None, "npy", "flo"):
            raise ValueError(f"`format` of flow() must be 'npy' or 'flo' (arrays), got {fmt!r}")
        options = {**options, "format": fmt or "npy"}

        def read(response: httpx2.Response) -> FlowResult:
            return FlowResult(flow=decode_flow(response.content), content=response.content,
                              media_type=response.headers.get("content-type", ""))
        return self._image_call("/v1/flow", image_a, image_b, options, read)

    def _confidence_call(self, image_a: ImageInput, image_b: ImageInput,
                         options: dict[str, Any]) -> _Call[ConfidenceResult]:
        fmt = options.get("format") or "npy"
        if fmt not in ("npy", "png"):
            raise ValueError(f"`format` of confidence() must be 'npy' or 'png', got {fmt!r}")
        options = {**options, "format": fmt}

        def read(response: httpx2.Response) -> ConfidenceResult:
            image = decode_image(response.content)
            conf = np.asarray(image, dtype=np.float32) / (255.0 if image.dtype == np.uint8 else 1.0)
            conf.setflags(write=False)
            return ConfidenceResult(confidence=conf, content=response.content,
                                    media_type=response.headers.get("content-type", ""))
        return self._image_call("/v1/confidence", image_a, image_b, options, read)

    def _filter_call(self, src: Any, dst: Any, method: str | None, seed: int | None,
                     options: dict[str, Any]) -> _Call[FilterResult]:
        src_json, dst_json = points_json(src, "src"), points_json(dst, "dst")
        body: dict[str, Any] = {"src": src_json, "dst": dst_json, **_method_seed(method, seed)}
        if options:
            body["options"] = json_options(options)
        return _Call("POST", "/v1/filter", lambda r: FilterResult.from_json(_json(r), src=src_json, dst=dst_json),
                     json=body)

    def _register_call(self, model: Any, target: Any, method: str | None, seed: int | None,
                       options: dict[str, Any], extras: dict[str, Any] | None = None) -> _Call[RegisterResult]:
        body: dict[str, Any] = {"model": scan_json(model, "model"), "target": scan_json(target, "target"),
                                **_method_seed(method, seed)}
        for key, value in (extras or {}).items():
            if key.endswith("_colors") and value is not None and np.asarray(value).dtype == np.uint8:
                value = np.asarray(value) / 255.0  # the service takes RGB in [0, 1]; 8-bit channels as held
            if value is not None:
                body[key] = scan_json(value, key)
        if options:
            body["options"] = json_options(options)
        return _Call("POST", "/v1/register", lambda r: RegisterResult.from_json(_json(r)), json=body)

    # ------------------------------------------------------------------ sending, shared parts
    def _request_kwargs(self, call: _Call[Any]) -> dict[str, Any]:
        kwargs: dict[str, Any] = {"timeout": self.timeout} if self._per_request_timeout else {}
        if self._headers:
            kwargs["headers"] = self._headers
        if call.json is not None:
            kwargs["json"] = call.json
        if call.files is not None:
            kwargs["files"] = call.files
            kwargs["data"] = call.data
        return kwargs

    def _retry_delay(self, call: _Call[Any], retry: int, response: httpx2.Response | None,
                     exc: Exception | None) -> float | None:
        """Seconds to wait before sending ``call`` again, or None when it must not be retried."""
        if retry >= self.retry.retries:
            return None
        if exc is not None:
            reason = f"{type(exc).__name__}: {exc}"
            retry_after = None
        elif response is not None and response.status_code in _RETRY_STATUS:
            retry_after = _retry_after(response)
            if retry_after is not None and retry_after > self.retry.max_retry_after:
                return None
            reason = f"HTTP {response.status_code}"
        else:
            return None
        wait = self.retry.delay(retry, retry_after, self._rng)
        log.info("%s %s: %s; retry %d of %d in %.2f s", call.method, call.path, reason, retry + 1,
                 self.retry.retries, wait)
        return wait

    @staticmethod
    def _finish(call: _Call[R], response: httpx2.Response) -> R:
        if response.is_error:
            raise _error_from_response(response)
        return _read(response, call.read)

    @staticmethod
    def _transport_error(call: _Call[Any], exc: httpx2.TransportError) -> ApiError:
        if isinstance(exc, httpx2.TimeoutException) and not isinstance(exc, httpx2.ConnectTimeout):
            return Timeout(None, detail=f"{call.method} {call.path}: no answer within the client's timeout "
                                        f"({type(exc).__name__})", title="Client timeout")
        return Unreachable(None, detail=f"{call.method} {call.path}: {type(exc).__name__}: {exc}",
                           title="Service unreachable")

    @staticmethod
    def _health(live: httpx2.Response, ready: httpx2.Response) -> Health:
        try:
            detail = ready.json()
        except ValueError:
            detail = {}
        return Health(live=live.status_code == 200, ready=ready.status_code == 200,
                      detail=MappingProxyType(detail if isinstance(detail, dict) else {}))

    @staticmethod
    def _pairs(pairs: PairInput,
               ) -> tuple[Iterator[tuple[Hashable, tuple[ImageInput, ImageInput]]], int | None]:
        if isinstance(pairs, Mapping):
            return iter(pairs.items()), len(pairs)
        total = len(pairs) if hasattr(pairs, "__len__") else None  # type: ignore[arg-type]
        return enumerate(pairs), total


class _Progress:
    """tqdm when it is installed and wanted, else the caller's callback, else nothing."""

    def __init__(self, progress: bool | ProgressCallback, total: int | None) -> None:
        self._callback: ProgressCallback | None = None
        self._bar: Any = None
        self._done = 0
        self._total = total
        if callable(progress):
            self._callback = progress
        elif progress:
            try:
                from tqdm.auto import tqdm  # type: ignore[import-untyped,unused-ignore]
            except ImportError:
                tqdm = None
            if tqdm is not None:
                self._bar = tqdm(total=total, desc="match", unit="pair")
            else:
                log.debug("tqdm is not installed; pass progress=<callback> to follow match_many")

    def step(self) -> None:
        self._done += 1
        if self._bar is not None:
            self._bar.update(1)
        if self._callback is not None:
            self._callback(self._done, self._total)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


_PAIR_ERRORS = (ApiError, OSError, ValueError, TypeError)


class Client(_Base):
    """Blocking client of the reglib service.

    Parameters
    ----------
    base_url : str
        Where the service answers, e.g. ``"http://127.0.0.1:8000"``.
    timeout : float, httpx2.Timeout or None
        Per request: seconds for everything, or an ``httpx2.Timeout`` with connect / read / write /
        pool parts; ``None`` waits forever. When left out: :data:`DEFAULT_TIMEOUT` (up to 120 s for
        an answer), or, with an ``http_client``, that client's own timeout. When given, it is
        applied to every request, also through a caller's ``http_client``.
    retries : int or RetryPolicy
        Retries after the first attempt, on connection failures and on 429 / 503 (see
        :class:`RetryPolicy`); never on other errors.
    http_client : httpx2.Client, optional
        Send through this client (e.g. a Starlette ``TestClient`` of the app, or one with your
        proxies and certificates). It is not closed by :meth:`close`.
    api_key : str, optional
        The service's API key, sent as ``Authorization: Bearer <key>`` with every request; when
        left out, ``$REGLIB_API_KEY`` if set, else none (a service without keys needs none). A
        missing or wrong key is an :class:`ApiError` with ``status`` 401.

    Examples
    --------
    >>> with Client("http://127.0.0.1:8000") as client:          # doctest: +SKIP
    ...     result = client.match("a.png", "b.png", features="sift")
    ...     result.transform(result.src[result.inliers])
    """

    def __init__(self, base_url: str, *, timeout: float | httpx2.Timeout | None = _UNSET,
                 retries: int | RetryPolicy = 3, http_client: httpx2.Client | None = None,
                 api_key: str | None = None) -> None:
        super().__init__(base_url, timeout=timeout, retries=retries, own_http=http_client is None, api_key=api_key)
        if http_client is not None and not isinstance(http_client, httpx2.Client):
            raise TypeError(f"`http_client` must be an httpx2.Client, got {type(http_client).__name__}")
        self._owns_http = http_client is None
        self._http = http_client if http_client is not None else httpx2.Client(timeout=self.timeout)
        if http_client is not None and not self._per_request_timeout:
            self.timeout = http_client.timeout

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection pool (not a caller's ``http_client``)."""
        if self._owns_http:
            self._http.close()

    def _send(self, call: _Call[R]) -> R:
        retry = 0
        while True:
            try:
                response = self._http.request(call.method, self._url(call.path), **self._request_kwargs(call))
            except httpx2.TransportError as exc:
                wait = self._retry_delay(call, retry, None, exc) if isinstance(exc, _RETRY_EXC) else None
                if wait is None:
                    raise self._transport_error(call, exc) from exc
            else:
                wait = self._retry_delay(call, retry, response, None)
                if wait is None:
                    return self._finish(call, response)
                response.close()
            _sleep(wait)
            retry += 1

    # ------------------------------------------------------------------ endpoints
    def match(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> MatchResult:
        """Match image a to image b: features, robust filtering, and the transform a -> b.

        Parameters
        ----------
        image_a, image_b : path, bytes, binary file object or (H, W[, C]) integer array
            Encoded images are sent as they are; arrays are encoded to PNG (colour as RGB).
        **options
            Form fields of ``/v1/match``, named like the library's options (``features``,
            ``method``, ``ratio``, ``max_keypoints``, ``dense``, ``seed``, ``filter={...}`` ...).
            An unknown name is rejected by the service (:class:`InvalidInput`), never ignored.

        Returns
        -------
        MatchResult
            Too few matches is a normal result with ``converged=False`` and a ``reason``.

        Raises
        ------
        InvalidInput, TooLarge, Overloaded, Timeout, Unreachable, ApiError
        """
        return self._send(self._match_call(image_a, image_b, options))

    def match_bundle(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> MatchBundle:
        """Match, and get the match's files in the same answer (``POST /v1/match/bundle``).

        Options as :meth:`match`, plus ``alpha`` (weight of warped b in ``overlay.png``). The bundle's
        ``files`` are ``warped.png``, ``overlay.png``, ``flow.png``, ``flow.flo`` and, when the match has
        a confidence map, ``confidence.png``; ``bundle.save(folder)`` writes them with ``match.json``
        and ``transform.json`` (the layout of ``reglib match --out``).

        Returns
        -------
        MatchBundle
        """
        return self._send(self._bundle_call(image_a, image_b, options))

    def warp(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> WarpResult:
        """Match, then resample image b onto image a's grid (it overlays a); options as :meth:`match`
        plus ``overlay``, ``alpha``, ``interpolation``."""
        return self._send(self._warp_call(image_a, image_b, options))

    def flow(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> FlowResult:
        """Match, then the dense forward flow a -> b as an (H_a, W_a, 2) float32 array of (dx, dy).

        ``format`` may be ``"npy"`` (the default) or ``"flo"``; other options as :meth:`match`.
        """
        return self._send(self._flow_call(image_a, image_b, options))

    def confidence(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> ConfidenceResult:
        """Match, then the (H_a, W_a) float32 confidence map of the flow in [0, 1] (``format`` "npy",
        the default, or "png"); other options as :meth:`match`."""
        return self._send(self._confidence_call(image_a, image_b, options))

    def filter(self, src: Any, dst: Any, *, method: str | None = None, seed: int | None = None,
               **options: Any) -> FilterResult:
        """Separate true from false putative matches (row i of ``src`` matches row i of ``dst``).

        Parameters
        ----------
        src, dst : (N, D) array_like, D in {2, 3}
            Points (x, y[, z]); for images x is the column.
        method : {"l2e", "vfc"}, optional
            The estimator (the service's default when None).
        seed : int, optional
            Random seed (the service's default, 0, when None); recorded in the result.
        **options
            Fields of the estimator's options (e.g. ``beta``, ``linear="affine"``), checked by the service.
        """
        return self._send(self._filter_call(src, dst, method, seed, options))

    def register(self, model: Any, target: Any, *, method: str | None = None, seed: int | None = None,
                 model_colors: Any = None, target_colors: Any = None, model_normals: Any = None,
                 target_normals: Any = None, **options: Any) -> RegisterResult:
        """Register the ``model`` point set (N, D) onto ``target`` (M, D) without correspondences.

        ``method`` is one of the service's registration methods (``"l2e"`` by default there; the
        rigid ones: ``"icp"``, ``"icp-hmrf"``, ``"color-gmm"``, ``"density-adaptive"``, ``"bayes"``);
        an organized (H, W, 3) scan may hold NaN where nothing was seen; ``model_colors`` /
        ``target_colors`` (RGB in [0, 1], or uint8 0-255) for ``"color-gmm"``, normals for ``"icp"``;
        ``**options`` are that method's options.
        """
        extras = {"model_colors": model_colors, "target_colors": target_colors, "model_normals": model_normals,
                  "target_normals": target_normals}
        return self._send(self._register_call(model, target, method, seed, options, extras))

    def health(self) -> Health:
        """Liveness and readiness, without retrying (a not-ready service is ``ready=False``, not an error).

        Raises
        ------
        Unreachable, Timeout
            When the service does not answer at all.
        """
        probe = _Call("GET", "/livez", lambda r: r)
        try:
            live = self._http.get(self._url("/livez"), **self._request_kwargs(probe))
            ready = self._http.get(self._url("/readyz"), **self._request_kwargs(probe))
        except httpx2.TransportError as exc:
            raise self._transport_error(probe, exc) from exc
        return self._health(live, ready)

    def match_many(self, pairs: PairInput,
                   *, concurrency: int = 4, progress: bool | ProgressCallback = True,
                   **options: Any) -> Iterator[PairOutcome[MatchResult]]:
        """Match many pairs with at most ``concurrency`` requests in flight; yield each as it finishes.

        Parameters
        ----------
        pairs : iterable of (image_a, image_b), or mapping key -> (image_a, image_b)
            Read lazily: a generator is consumed only as fast as requests go out.
        concurrency : int
            Requests in flight at most (threads sharing this client's connection pool).
        progress : bool or callable
            True: a tqdm bar when tqdm is installed (``pip install reglib-client[progress]``),
            nothing otherwise; a callable is called as ``progress(done, total)`` after every pair
            (total None for an iterator of unknown length); False: no progress.
        **options
            As :meth:`match`, for every pair.

        Yields
        ------
        PairOutcome
            ``key`` (mapping key or position), and ``result`` or ``error``: one pair's failure
            (an :class:`ApiError`, or its images could not be read) never stops the others.
        """
        if isinstance(concurrency, bool) or not isinstance(concurrency, int) or concurrency < 1:
            raise ValueError(f"`concurrency` must be an integer >= 1, got {concurrency!r}")
        items, total = self._pairs(pairs)
        bar = _Progress(progress, total)

        def one(key: Hashable, pair: tuple[ImageInput, ImageInput]) -> PairOutcome[MatchResult]:
            try:
                image_a, image_b = pair
                return PairOutcome(key=key, result=self.match(image_a, image_b, **options))
            except _PAIR_ERRORS as exc:
                return PairOutcome(key=key, error=exc)

        pool = concurrent.futures.ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="reglib-client")
        pending: set[concurrent.futures.Future[PairOutcome[MatchResult]]] = set()
        try:
            exhausted = False
            while True:
                while not exhausted and len(pending) < concurrency:
                    try:
                        key, pair = next(items)
                    except StopIteration:
                        exhausted = True
                        break
                    pending.add(pool.submit(one, key, pair))
                if not pending:
                    return
                done, pending = concurrent.futures.wait(pending, return_when=concurrent.futures.FIRST_COMPLETED)
                for future in done:
                    bar.step()
                    yield future.result()
        finally:
            for future in pending:
                future.cancel()
            pool.shutdown(wait=True, cancel_futures=True)
            bar.close()


class AsyncClient(_Base):
    """asyncio client of the reglib service: :class:`Client`'s methods as coroutines.

    Parameters are those of :class:`Client`; ``http_client`` is an ``httpx2.AsyncClient`` (e.g.
    one on ``httpx2.ASGITransport(app)`` in tests). Use ``async with AsyncClient(...) as client``.
    """

    def __init__(self, base_url: str, *, timeout: float | httpx2.Timeout | None = _UNSET,
                 retries: int | RetryPolicy = 3, http_client: httpx2.AsyncClient | None = None,
                 api_key: str | None = None) -> None:
        super().__init__(base_url, timeout=timeout, retries=retries, own_http=http_client is None, api_key=api_key)
        if http_client is not None and not isinstance(http_client, httpx2.AsyncClient):
            raise TypeError(f"`http_client` must be an httpx2.AsyncClient, got {type(http_client).__name__}")
        self._owns_http = http_client is None
        self._http = http_client if http_client is not None else httpx2.AsyncClient(timeout=self.timeout)
        if http_client is not None and not self._per_request_timeout:
            self.timeout = http_client.timeout

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        """Close the connection pool (not a caller's ``http_client``)."""
        if self._owns_http:
            await self._http.aclose()

    async def _send(self, call: _Call[R]) -> R:
        retry = 0
        while True:
            try:
                response = await self._http.request(call.method, self._url(call.path), **self._request_kwargs(call))
            except httpx2.TransportError as exc:
                wait = self._retry_delay(call, retry, None, exc) if isinstance(exc, _RETRY_EXC) else None
                if wait is None:
                    raise self._transport_error(call, exc) from exc
            else:
                wait = self._retry_delay(call, retry, response, None)
                if wait is None:
                    return self._finish(call, response)
                await response.aclose()
            await _async_sleep(wait)
            retry += 1

    async def match(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> MatchResult:
        """As :meth:`Client.match`."""
        # Reading files and encoding arrays to PNG happen off the event loop.
        return await self._send(await asyncio.to_thread(self._match_call, image_a, image_b, options))

    async def match_bundle(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> MatchBundle:
        """As :meth:`Client.match_bundle`."""
        return await self._send(await asyncio.to_thread(self._bundle_call, image_a, image_b, options))

    async def warp(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> WarpResult:
        """As :meth:`Client.warp`."""
        # Reading files and encoding arrays to PNG happen off the event loop.
        return await self._send(await asyncio.to_thread(self._warp_call, image_a, image_b, options))

    async def flow(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> FlowResult:
        """As :meth:`Client.flow`."""
        # Reading files and encoding arrays to PNG happen off the event loop.
        return await self._send(await asyncio.to_thread(self._flow_call, image_a, image_b, options))

    async def confidence(self, image_a: ImageInput, image_b: ImageInput, **options: Any) -> ConfidenceResult:
        """As :meth:`Client.confidence`."""
        return await self._send(await asyncio.to_thread(self._confidence_call, image_a, image_b, options))

    async def filter(self, src: Any, dst: Any, *, method: str | None = None, seed: int | None = None,
                     **options: Any) -> FilterResult:
        """As :meth:`Client.filter`."""
        return await self._send(self._filter_call(src, dst, method, seed, options))

    async def register(self, model: Any, target: Any, *, method: str | None = None, seed: int | None = None,
                       model_colors: Any = None, target_colors: Any = None, model_normals: Any = None,
                       target_normals: Any = None, **options: Any) -> RegisterResult:
        """As :meth:`Client.register`."""
        extras = {"model_colors": model_colors, "target_colors": target_colors, "model_normals": model_normals,
                  "target_normals": target_normals}
        return await self._send(self._register_call(model, target, method, seed, options, extras))

    async def health(self) -> Health:
        """As :meth:`Client.health`."""
        probe = _Call("GET", "/livez", lambda r: r)
        try:
            live = await self._http.get(self._url("/livez"), **self._request_kwargs(probe))
            ready = await self._http.get(self._url("/readyz"), **self._request_kwargs(probe))
        except httpx2.TransportError as exc:
            raise self._transport_error(probe, exc) from exc
        return self._health(live, ready)

    async def match_many(self, pairs: PairInput,
                         *, concurrency: int = 4, progress: bool | ProgressCallback = True,
                         **options: Any) -> AsyncIterator[PairOutcome[MatchResult]]:
        """As :meth:`Client.match_many`, as an async iterator: ``async for outcome in client.match_many(...)``."""
        if isinstance(concurrency, bool) or not isinstance(concurrency, int) or concurrency < 1:
            raise ValueError(f"`concurrency` must be an integer >= 1, got {concurrency!r}")
        items, total = self._pairs(pairs)
        bar = _Progress(progress, total)

        async def one(key: Hashable, pair: tuple[ImageInput, ImageInput]) -> PairOutcome[MatchResult]:
            try:
                image_a, image_b = pair
                return PairOutcome(key=key, result=await self.match(image_a, image_b, **options))
            except _PAIR_ERRORS as exc:
                return PairOutcome(key=key, error=exc)

        pending: set[asyncio.Task[PairOutcome[MatchResult]]] = set()
        try:
            exhausted = False
            while True:
                while not exhausted and len(pending) < concurrency:
                    try:
                        key, pair = next(items)
                    except StopIteration:
                        exhausted = True
                        break
                    pending.add(asyncio.ensure_future(one(key, pair)))
                if not pending:
                    return
                done, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
                for task in done:
                    bar.step()
                    yield task.result()
        finally:
            for task in pending:
                task.cancel()
            if pending:
                await asyncio.gather(*pending, return_exceptions=True)
            bar.close()
