"""The pages beside the API: /docs and /redoc work offline, the web page has no inline script and offers the
README's example pair, and /metrics labels each of them by its route, not as "unmatched"."""
from __future__ import annotations

import re
from html.parser import HTMLParser

import pytest

from reglib.examples import example_pair

# anything that names a host: a scheme or a protocol-relative URL
EXTERNAL = re.compile(r"(?i)(\b[a-z][a-z0-9+.-]*:)?//[a-z0-9-]+(\.[a-z0-9-]+)+")


class _Links(HTMLParser):
    """Every src / href / spec-url of a page, and the inline scripts and on* handlers it has."""

    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []
        self.inline_scripts: list[str] = []
        self.handlers: list[str] = []
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        values = dict(attrs)
        self.links += [v for k, v in attrs if k in ("src", "href", "spec-url") and v]
        self.handlers += [k for k, _ in attrs if k.startswith("on")]
        self._in_script = tag == "script" and "src" not in values

    def handle_endtag(self, tag):
        self._in_script = False

    def handle_data(self, data):
        if self._in_script and data.strip():
            self.inline_scripts.append(data)


def _links(html: str) -> _Links:
    parser = _Links()
    parser.feed(html)
    return parser


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_docs_name_no_external_host_and_every_asset_is_served(client, page):
    r = client.get(page)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    html = r.text
    assert EXTERNAL.search(html) is None, EXTERNAL.search(html)
    links = _links(html).links
    scripts = [link for link in links if link.endswith(".js")]
    assert scripts, links  # the page loads its UI from the service
    # Swagger UI names its document in its start-up script; ReDoc in spec-url
    named = set(links) | set(re.findall(r"url: '([^']+)'", html))
    assert "/openapi.json" in named
    for link in sorted(named):
        assert link.startswith("/"), link
        asset = client.get(link)
        assert asset.status_code == 200, link
        assert len(asset.content) > 100, link
        if link.endswith(".js"):
            assert "javascript" in asset.headers["content-type"], link
        if link.endswith(".css"):
            assert asset.headers["content-type"].startswith("text/css"), link


def test_the_swagger_ui_asks_no_online_validator(client):
    assert '"validatorUrl": null' in client.get("/docs").text


def test_the_page_has_no_inline_script(client):
    for path in ("/", "/static/index.html"):
        found = _links(client.get(path).text)
        assert not found.inline_scripts and not found.handlers, path
        assert "/static/app.js" in found.links
        assert not [link for link in found.links if EXTERNAL.search(link)], found.links


def test_the_examples_are_the_readmes_pair(client):
    pair = client.get("/examples").json()
    for name, path in zip(("image_a", "image_b"), example_pair(), strict=True):
        assert pair[name] == f"/examples/{path.name}"
        r = client.get(pair[name])
        assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
        assert r.content == path.read_bytes()
    # nothing else of the folder is served
    r = client.get("/examples/__init__.py")
    assert r.status_code == 404 and r.headers["content-type"].startswith("application/problem+json")


def _requests(client) -> dict[tuple[str, str, str], float]:
    counts = {}
    for line in client.get("/metrics").text.splitlines():
        m = re.match(r'reglib_http_requests_total\{method="([^"]*)",route="([^"]*)",status="([^"]*)"\} (\S+)', line)
        if m:
            counts[m.group(1, 2, 3)] = float(m.group(4))
    return counts


def test_metrics_label_the_docs_and_their_assets_by_route(client):
    asked = {"/docs": "/docs", "/redoc": "/redoc", "/openapi.json": "/openapi.json",
             "/docs/oauth2-redirect": "/docs/oauth2-redirect", "/static/style.css": "/static",
             "/examples/cat_a.jpg": "/examples/{name}"}
    assets = [link for link in _links(client.get("/docs").text).links + _links(client.get("/redoc").text).links
              if link.startswith("/docs/assets/")]
    assert assets
    before = _requests(client)
    for path in [*asked, *assets]:
        assert client.get(path).status_code == 200, path
    assert client.get("/no-such-page").status_code == 404
    assert client.get("/v1/match/bundle").status_code == 405
    after = _requests(client)

    def delta(method, route, status):
        key = (method, route, status)
        return after.get(key, 0.0) - before.get(key, 0.0)

    for route in asked.values():
        assert delta("GET", route, "200") >= 1, route
    assert delta("GET", "/docs/assets", "200") == len(assets)
    assert delta("GET", "unmatched", "404") == 1  # only the path that nothing serves
    assert delta("GET", "/v1/match/bundle", "405") == 1
    assert delta("GET", "unmatched", "200") == 0


def test_redoc_keeps_every_fetch_on_this_origin(client):
    policy = client.get("/redoc").headers["content-security-policy"]
    directives = dict(part.strip().split(" ", 1) for part in policy.split(";"))
    assert directives["default-src"] == "'self'" and directives["img-src"] == "'self' data:"
