"""The browser page: ``GET /`` and its two assets, ``/web/app.js`` and ``/web/style.css`` (``api/web/``).

No outside assets: the page's script and style are small files of this package, and the
``Content-Security-Policy`` allows nothing but this origin (images of the plots come in as ``blob:``
URLs, fetched with the API key). What the page needs to know about the service (the structures,
the spec's fields, their defaults and which take null, the objectives, the budget limits, the trade-off's
axes) is put into the page as JSON, so the form cannot drift from the library. The page is public like
``/docs``: the API key, when the service has one, is entered in the page and sent as ``X-API-Key`` by its
requests.
"""

from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.responses import HTMLResponse, Response

from ..schemas import TradeoffRequest
from ..settings import Settings, get_settings

__all__ = ["router", "WEB", "CSP", "page_config"]

router = APIRouter(include_in_schema=False)

WEB = Path(__file__).resolve().parent.parent / "web"
CSP = ("default-src 'self'; img-src 'self' blob: data:; script-src 'self'; style-src 'self'; "
       "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'")
_ASSETS = {"app.js": "text/javascript; charset=utf-8", "style.css": "text/css; charset=utf-8"}


def page_config(settings: Settings) -> dict[str, Any]:
    """What the form is built from: structures (parameters, discrete only), spec fields, limits."""
    from tuner.controllers import DEPRECATED_STRUCTURES, STRUCTURES
    from tuner.firmware.registry import firmwares
    from tuner.limits import EFFORT_NAMES, page_limits
    from tuner.spec import DEFAULT_LIMITS, OBJECTIVES, Spec
    from tuner.tradeoff import MAX_POINTS, Y_AXES

    schema = Spec.model_json_schema()["properties"]
    return {
        "structures": [{"name": s.name, "params": list(s.params), "discrete_only": s.discrete_only}
                       for s in STRUCTURES.values()],
        "deprecated_structures": dict(DEPRECATED_STRUCTURES),  # old name -> new (a stored tune's form)
        # every registered firmware (tuner.firmware.registry): its law, its parameter file, its loop rate's name
        "firmwares": [{"name": f.name, "title": f.title, "structure": f.structure, "format": f.export_format,
                       "suffix": f.suffix, "files": f.files, "loop_param": f.names("roll")["loop_hz"]}
                      for f in firmwares()],
        "objectives": ["auto", *OBJECTIVES],  # (auto, the default: the structure decides)
        "spec_defaults": Spec().model_dump(mode="json"),
        "spec_help": {k: v.get("description", "") for k, v in schema.items()},
        # the fields that take null (an empty input sends null: a default limit such as filter_n_max is lifted)
        "spec_nullable": [k for k, v in schema.items() if any(a.get("type") == "null" for a in v.get("anyOf", ()))],
        "default_limits": list(DEFAULT_LIMITS),
        "limits": page_limits(),  # the optional limits' inputs (the registry, tuner.limits)
        "efforts": list(EFFORT_NAMES),
        "tradeoff": {"y": list(Y_AXES), "max_points": MAX_POINTS,
                     "default_points": TradeoffRequest.model_fields["points"].default},
        "default_budget_s": settings.default_budget_s,
        "max_budget_s": settings.max_budget_s,
        "max_plants": settings.max_plants,
        "api_key_required": settings.api_key is not None,
    }


@lru_cache(maxsize=8)
def _page(config_json: str) -> str:
    return (WEB / "index.html").read_text(encoding="utf-8").replace("{{CONFIG}}", config_json)


@lru_cache(maxsize=len(_ASSETS))
def _asset(name: str) -> tuple[bytes, str]:
    data = (WEB / name).read_bytes()
    return data, '"' + hashlib.sha256(data).hexdigest()[:16] + '"'


@router.get("/", response_class=HTMLResponse)
async def page(settings: Settings = Depends(get_settings)) -> HTMLResponse:
    config = json.dumps(page_config(settings), sort_keys=True).replace("</", "<\\/")
    return HTMLResponse(_page(config), headers={"Content-Security-Policy": CSP, "Cache-Control": "no-cache",
                                                "X-Content-Type-Options": "nosniff", "Referrer-Policy": "same-origin"})


@router.get("/web/{name}")
async def asset(name: str, request: Request) -> Response:
    if name not in _ASSETS:
        raise HTTPException(404, f"no page asset {name!r}")
    data, etag = _asset(name)
    headers = {"ETag": etag, "Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"}
    if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
        return Response(status_code=304, headers=headers)
    return Response(data, media_type=_ASSETS[name], headers=headers)
