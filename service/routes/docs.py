"""The API docs: ``/docs`` (Swagger UI), its OAuth2 redirect page, and ``/redoc``, served offline.

``fastapi-offline`` ships their scripts and styles (mounted at :data:`DOCS_ASSETS`); these routes write the
pages themselves so that each carries a Content-Security-Policy of its own: everything from this origin,
and the inline start-up script of Swagger UI allowed by its SHA-256 (computed from the very page sent),
never by ``'unsafe-inline'``. ReDoc injects its styles and runs its search in a ``blob:`` worker, which its
policy allows; its script would still fetch its maker's logo from a CDN, which the policy stops (the logo
then hides itself).
"""
from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse

from ..headers import inline_script_policy

__all__ = ["router", "DOCS_ASSETS", "SWAGGER_CSP", "REDOC_CSP"]

router = APIRouter(include_in_schema=False)

#: Where the API docs' scripts, styles and icon are served (from the ``fastapi-offline`` package).
DOCS_ASSETS = "/docs/assets"
#: ``/docs``'s policy; ``script-src`` gains the hash of the page's inline script.
SWAGGER_CSP = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
               "object-src 'none'; base-uri 'none'; frame-ancestors 'none'")
#: ``/redoc``'s policy: everything from this origin (ReDoc injects styles and runs its search in a blob: worker).
REDOC_CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; "
             "worker-src 'self' blob:; object-src 'none'; base-uri 'none'; frame-ancestors 'none'")
OAUTH2_REDIRECT = "/docs/oauth2-redirect"


def _hashed(page: HTMLResponse) -> HTMLResponse:
    page.headers["Content-Security-Policy"] = inline_script_policy(bytes(page.body).decode(), SWAGGER_CSP)
    return page


@router.get("/docs")
async def swagger(request: Request) -> HTMLResponse:
    app = request.app
    root = request.scope.get("root_path", "")
    return _hashed(get_swagger_ui_html(
        openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - Swagger UI",
        oauth2_redirect_url=f"{root}{OAUTH2_REDIRECT}", swagger_js_url=f"{root}{DOCS_ASSETS}/swagger-ui-bundle.js",
        swagger_css_url=f"{root}{DOCS_ASSETS}/swagger-ui.css", swagger_favicon_url=f"{root}{DOCS_ASSETS}/favicon.png",
        swagger_ui_parameters=app.swagger_ui_parameters))


@router.get(OAUTH2_REDIRECT)
async def swagger_redirect() -> HTMLResponse:
    return _hashed(get_swagger_ui_oauth2_redirect_html())


@router.get("/redoc")
async def redoc(request: Request) -> HTMLResponse:
    app = request.app
    root = request.scope.get("root_path", "")
    page = get_redoc_html(openapi_url=f"{root}{app.openapi_url}", title=f"{app.title} - ReDoc",
                          redoc_js_url=f"{root}{DOCS_ASSETS}/redoc.standalone.js",
                          redoc_favicon_url=f"{root}{DOCS_ASSETS}/favicon.png", with_google_fonts=False)
    page.headers["Content-Security-Policy"] = REDOC_CSP
    return page
